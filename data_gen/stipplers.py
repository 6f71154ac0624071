"""Point patterns made by other methods than the synthesiser, from a density image.

The network must not learn the synthesiser's fingerprint: its training pairs
and its out-of-distribution evaluation also use point sets from other
stipplers and reference processes, each with a known correlation label
(:data:`LABELS`, a preset name of the palette). This module needs only numpy,
scipy and Pillow (no ``synthesis`` import), so the fidelity bench can use it
as an independent yardstick too (``bench/fidelity_stats.py`` re-exports
:func:`lloyd_stipple`, :func:`stratified_start` and :func:`poisson_disk`).

Conventions: ``density`` is an (H, W) array in [0, 1] covering the domain
``[0, w] x [0, h]`` with ``max(w, h) = 1`` and square pixels (row 0 at y = 0);
a method returns (n, 2) float64 positions in the domain, y down.

=================  =========================================================  =======
method             what it does                                               label
=================  =========================================================  =======
``random``         density-proportional Poisson: pixel by density, uniform    white
                   inside it
``lloyd``          weighted Voronoi stippling (Secord 2002), CVT by density   blue
``poisson_disk``   dart throwing with a radius of 0.7 local spacings (the     blue
                   spacing of the density at each candidate)
``jitter``         a jittered grid warped by the density's inverse CDF        jitter
``clusters``       Thomas process: density-proportional parents, Gaussian     red
                   offspring at 0.6 local spacings
``floyd_steinberg``  error-diffusion dithering (Pillow) on a grid of about n  measured
                   inked pixels (:func:`ink_grid`)
``jarvis``         error diffusion, Jarvis-Judice-Ninke kernel, raster scan   measured
``floyd_steinberg_jitter``  Floyd-Steinberg, serpentine scan, each point      measured
                   moved uniformly within +-0.35 pixel
``bayer``          ordered dithering, 8 x 8 Bayer matrix at a random offset   measured
``lloyd_few``      weighted Lloyd, 4 iterations (not converged)               measured
``lloyd_many``     weighted Lloyd, 150 iterations                             measured
``lattice_square``, a square or hexagonal lattice at a random rotation and    measured
``lattice_hex``    offset, Gaussian jitter 0.05 spacings (``_jitter``: 0.2),
(``_jitter``)      warped to the density by its inverse CDF
``matern_tight``,  Matérn cluster processes: density-proportional parents,    measured
``matern_dense``,  points uniform in discs around them; points per parent
``matern_loose``,  and disc radius (local mean spacings) 6 and 0.45, 12 and
``matern_wide``    0.85, 6 and 0.85, 4 and 1.6
=================  =========================================================  =======

Frozen test-set methods (:data:`FROZEN_METHODS`; docs/evaluation.md), never used for training pairs:
``sierra_serpentine`` (error diffusion, Sierra-3 kernel, serpentine scan) and ``capacity_voronoi``
(capacity-constrained Voronoi stippling, :func:`capacity_lloyd_stipple`, 30 iterations).

Measured labels (``python bench/stippler_labels.py --seeds 2``, file ``bench/stippler_labels.json``): each
method stipples constant densities 0.2, 0.4 and 0.6 with 2048 points on the unit square at seeds 0 and 1 (the
lattices at a random rotation and offset per seed); the shipped palette decodes each sample
(:meth:`synthesis.palette.Palette.locate`, ``patternshop analyze``'s colour, which does not depend on the
orientation); mean a, b, spread = RMS distance of the six samples to their mean (ab units), nearest preset and
its distance:

=========================  ======  ======  ======  ========  =====
method                     a       b       spread  nearest   dist.
=========================  ======  ======  ======  ========  =====
``random``                 2.4     -0.4    0.1     white     2.4
``lloyd``                  16.8    -56.6   0.1     blue      8.6
``poisson_disk``           24.9    -50.7   0.0     blue      1.6
``jitter``                 20.7    -28.8   0.2     step      6.8
``clusters``               56.9    44.2    8.6     red       10.2
``floyd_steinberg``        24.4    -48.1   3.1     blue      4.0
``jarvis``                 25.2    -38.0   5.6     step      7.8
``floyd_steinberg_jitter`` 23.6    -40.2   7.1     step      7.7
``bayer``                  24.5    -45.1   6.1     blue      6.9
``lloyd_few``              18.4    -55.5   0.5     blue      6.7
``lloyd_many``             16.8    -56.6   0.1     blue      8.6
``lattice_square``         -43.6   -43.9   0.1     lattice   3.3
``lattice_hex``            -25.6   -56.9   0.1     lattice   18.9
``lattice_square_jitter``  23.5    -43.3   0.0     blue      8.8
``lattice_hex_jitter``     24.5    -43.2   0.0     blue      8.8
``matern_tight``           -99.7   21.4    1.0     matern    3.1
``matern_dense``           -78.9   45.9    3.7     green     29.1
``matern_loose``           51.3    35.8    9.3     red       11.7
``matern_wide``            14.0    3.0     1.3     white     14.4
``sierra_serpentine``      25.3    -37.6   5.9     step      7.7
``capacity_voronoi``       1.8     -60.7   0.8     lloyd     7.8
=========================  ======  ======  ======  ========  =====

The Matérn variants give the network stationary clusters from other methods across the palette's cluster side
(``clusters`` is labelled red, 10 ab from what ``analyze`` reads, and its points read 57, 44): their parameters were
picked from a grid of 4 x 3 (points per parent 4-24, radius 0.4-1.5 r_max) explored beside ``bench_rotation.py``'s
Thomas process, which reads -81, 44; ``matern_dense`` lands 3 ab from it, so that bench row is no longer an unseen
colour once a model trains on these (the process itself, Gaussian offspring, stays out of training).

The five first methods keep their preset labels (the shipped model's pairs); the others are labelled with their
measured a, b, which ``tests/test_training_sources.py`` re-measures for the lattices. Network v10's pairs' lattices
carried labels decoded by the palette before its features became orientation free ((-12.2, -55.4) for the square
lattice, 18 ab units of spread over rotations), 34 ab units from what ``analyze`` reads today.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

SQRT3 = math.sqrt(3.0)
SQRT2 = math.sqrt(2.0)
CLUSTER_POINTS = 16  # Thomas offspring per parent on average (as synthesis.generators.red)
CLUSTER_STD_SPACINGS = 0.6  # offspring spread, local mean spacings
DISK_RADIUS_SPACINGS = 0.7  # Poisson-disk radius, local r_max (hexagonal spacing)
DISK_CANDIDATES = 12  # dart-throwing candidates per wanted point

Method = Callable[[np.ndarray, int, tuple[float, float], np.random.Generator], np.ndarray]


def r_max(n: int, area: float) -> float:
    """Spacing of the hexagonal lattice with ``n`` points in ``area``."""
    return 2.0 * math.sqrt(area / (2.0 * SQRT3 * n))


def pixel_size(density: np.ndarray, domain: tuple[float, float]) -> float:
    """Side of one square pixel of ``density`` in domain units."""
    return max(domain) / max(np.shape(density))


def random_stipple(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """n independent points, density-proportional: a pixel drawn by its density, then uniform inside it."""
    weights = np.asarray(density, np.float64).reshape(-1)
    pick = rng.choice(weights.size, size=n, p=weights / weights.sum())
    row, col = np.divmod(pick, np.shape(density)[1])
    return (np.stack([col, row], 1) + rng.random((n, 2))) * pixel_size(density, domain)


def stratified_start(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """n points, density-proportional and stratified: jittered inverse-CDF sampling along a
    boustrophedon (serpentine) pixel order, uniform within the chosen pixel."""
    H, W = density.shape
    order = np.arange(H * W).reshape(H, W)
    order[1::2] = order[1::2, ::-1]
    order = order.reshape(-1)
    weights = density.reshape(-1)[order].astype(np.float64)
    cdf = np.cumsum(weights)
    cdf /= cdf[-1]
    u = (np.arange(n) + rng.random(n)) / n
    pick = order[np.minimum(np.searchsorted(cdf, u, side="right"), H * W - 1)]
    row, col = np.divmod(pick, W)
    return (np.stack([col, row], 1) + rng.random((n, 2))) * pixel_size(density, domain)


def lloyd_stipple(density: np.ndarray, n: int, domain: tuple[float, float] = (1.0, 1.0), iterations: int = 60,
                  seed: int = 0, supersample: int = 1) -> np.ndarray:
    """Weighted Voronoi stippling (Secord 2002): centroidal Voronoi tessellation with the density
    as weight, on the pixel grid (optionally supersampled), from a stratified start.

    Each iteration assigns every pixel centre to its nearest point (cKDTree) and moves each point
    to the density-weighted centroid of its pixels (np.bincount); a point whose cell has no
    weight stays where it is. Use at least a few pixels per point (the centroids live on the grid).
    """
    rng = np.random.default_rng(seed)
    dens = np.asarray(density, np.float64)
    if supersample > 1:
        dens = np.kron(dens, np.ones((supersample, supersample)))
    H, W = dens.shape
    pixel = pixel_size(dens, domain)
    xy = stratified_start(dens, n, domain, rng)
    rows, cols = np.mgrid[0:H, 0:W]
    centres = np.stack([(cols.reshape(-1) + 0.5) * pixel, (rows.reshape(-1) + 0.5) * pixel], 1)
    weight = dens.reshape(-1)
    keep = weight > 0
    centres, weight = centres[keep], weight[keep]
    for _ in range(iterations):
        _, owner = cKDTree(xy).query(centres)
        mass = np.bincount(owner, weight, minlength=n)
        sx = np.bincount(owner, weight * centres[:, 0], minlength=n)
        sy = np.bincount(owner, weight * centres[:, 1], minlength=n)
        moved = mass > 0
        xy[moved, 0] = sx[moved] / mass[moved]
        xy[moved, 1] = sy[moved] / mass[moved]
    return xy


def capacity_lloyd_stipple(density: np.ndarray, n: int, domain: tuple[float, float] = (1.0, 1.0), iterations: int = 50,
                           seed: int = 0, balance: int = 3, start: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Capacity-constrained Voronoi stippling: Lloyd's centroid moves on power cells of equal ink.

    Where Lloyd's Voronoi cells hold whatever ink they cover, here every point owns ink 1/n of the total
    (the capacity constraint of Balzer et al. 2009's CCVT, reached as in semi-discrete optimal transport,
    de Goes et al. 2012): each pixel centre goes to the point minimising ``|x - p_i|^2 - w_i`` (a power
    diagram; cKDTree on lifted coordinates ``(p_i, sqrt(max w - w_i))``), the weights rise where a cell
    holds too little ink, ``w_i += 0.5 (1/n - m_i) / (sqrt(3) ink per area of the cell)`` (a hexagonal cell's
    area grows by sqrt(3) per unit of weight; a step is at most a tenth of the mean cell area), ``balance`` times per iteration, then every point moves to its
    power cell's ink centroid. Starts from :func:`stratified_start` (or ``start``). Returns the points and
    the final capacity spread: the largest ``|m_i n - 1|`` over the points (pixel-discrete: a pixel is
    about ``n / pixels`` of a capacity).
    """
    rng = np.random.default_rng(seed)
    dens = np.asarray(density, np.float64)
    H, W = dens.shape
    pixel = pixel_size(dens, domain)
    xy = stratified_start(dens, n, domain, rng) if start is None else np.array(start, np.float64)
    rows, cols = np.mgrid[0:H, 0:W]
    centres = np.stack([(cols.reshape(-1) + 0.5) * pixel, (rows.reshape(-1) + 0.5) * pixel], 1)
    weight = dens.reshape(-1)
    keep = weight > 0
    centres, weight = centres[keep], weight[keep] / weight[keep].sum()
    lifted = np.concatenate([centres, np.zeros((len(centres), 1))], axis=1)
    power = np.zeros(n)
    capacity = 1.0 / n
    limit = 0.1 * domain[0] * domain[1] / n
    spread = math.inf
    for _ in range(iterations):
        for _ in range(balance):
            sites = np.concatenate([xy, np.sqrt(power.max() - power)[:, None]], axis=1)
            _, owner = cKDTree(sites).query(lifted)
            mass = np.bincount(owner, weight, minlength=n)
            area = np.bincount(owner, minlength=n) * pixel * pixel
            per_area = np.where(mass > 0, mass / np.maximum(area, 1e-300), 1.0 / (domain[0] * domain[1]))
            # at most a tenth of a mean cell's area per balancing (a cell on paper, with little ink per area, overshot)
            power += np.clip(0.5 * (capacity - mass) / (SQRT3 * per_area), -limit, limit)
        spread = float(np.abs(mass * n - 1.0).max())
        sx = np.bincount(owner, weight * centres[:, 0], minlength=n)
        sy = np.bincount(owner, weight * centres[:, 1], minlength=n)
        moved = mass > 0
        xy[moved, 0] = sx[moved] / mass[moved]
        xy[moved, 1] = sy[moved] / mass[moved]
    return xy, spread


def poisson_disk(n: int, seed: int) -> np.ndarray:
    """scipy's ``qmc.PoissonDisk`` on the unit square (bounded), filled to saturation
    (``fill_space``) at radius 0.725 r_max(n): about n points (within ~2 %; statistics use its
    own count). Stopping ``random(n)`` before saturation would leave the last region unfilled
    (Bridson-style growth), i.e. a hole that is an artefact of the call, not of the process."""
    from scipy.stats import qmc

    engine = qmc.PoissonDisk(d=2, radius=0.725 * r_max(n, 1.0), seed=np.random.default_rng(seed))
    return engine.fill_space()


def local_r_max(density: np.ndarray, n: int, domain: tuple[float, float], xy: np.ndarray) -> np.ndarray:
    """(k,) hexagonal spacing at positions xy (k, 2) of n points distributed by ``density`` (nearest pixel)."""
    H, W = density.shape
    pixel = pixel_size(density, domain)
    col = np.clip((xy[:, 0] / pixel).astype(np.int64), 0, W - 1)
    row = np.clip((xy[:, 1] / pixel).astype(np.int64), 0, H - 1)
    mean = float(np.mean(density)) * domain[0] * domain[1]  # ink in the domain
    intensity = n * np.maximum(density[row, col], 1e-3) / mean
    return 2.0 / np.sqrt(2.0 * SQRT3 * intensity)


def variable_poisson_disk(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """Up to n points by dart throwing: density-proportional candidates, each kept unless a kept point lies
    within the mean of their radii (:data:`DISK_RADIUS_SPACINGS` local r_max each, at most the candidates'
    99th percentile). Usually exactly n."""
    candidates = random_stipple(density, DISK_CANDIDATES * n, domain, rng)
    radii = DISK_RADIUS_SPACINGS * local_r_max(density, n, domain, candidates)
    radii = np.minimum(radii, np.quantile(radii, 0.99))  # the lightest 1 %: no wider than the rest (keeps cells small)
    cell = float(radii.max())
    grid: dict[tuple[int, int], list[int]] = {}
    kept: list[int] = []
    for index, ((x, y), radius) in enumerate(zip(candidates, radii, strict=True)):
        i, j = int(y / cell), int(x / cell)
        near = [k for di in (-1, 0, 1) for dj in (-1, 0, 1) for k in grid.get((i + di, j + dj), ())]
        if near:
            others = candidates[near]
            if np.any(np.hypot(others[:, 0] - x, others[:, 1] - y) < 0.5 * (radii[near] + radius)):
                continue
        grid.setdefault((i, j), []).append(index)
        kept.append(index)
        if len(kept) == n:
            break
    return candidates[kept]


def warped_jitter(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """n points of a jittered grid (one per cell of a ``ceil(sqrt(n))``-square grid, n cells drawn) on the
    unit square, mapped to the domain by the density's inverse CDF (rows by their ink, then within the row)."""
    side = math.isqrt(n - 1) + 1
    cells = rng.choice(side * side, size=n, replace=False)
    uv = (np.stack([cells % side, cells // side], 1) + rng.random((n, 2))) / side
    return warp_by_density(uv, density, domain)


def warp_by_density(uv: np.ndarray, density: np.ndarray, domain: tuple[float, float]) -> np.ndarray:
    """(k, 2) positions in the domain of points uv (k, 2) in the unit square, mapped by the density's inverse CDF
    (rows by their ink, then within the row): a uniform pattern becomes density-proportional, and a constant
    density maps it linearly (a lattice stays a lattice)."""
    dens = np.asarray(density, np.float64) + 1e-12
    H, W = dens.shape
    pixel = pixel_size(dens, domain)
    row_cdf = np.concatenate([[0.0], np.cumsum(dens.sum(axis=1))])
    row_cdf /= row_cdf[-1]
    y_pixels = np.interp(uv[:, 1], row_cdf, np.arange(H + 1))
    row = np.clip(y_pixels.astype(np.int64), 0, H - 1)
    col_cdf = np.concatenate([np.zeros((H, 1)), np.cumsum(dens, axis=1)], axis=1)
    col_cdf /= col_cdf[:, -1:]
    x_pixels = np.array([np.interp(u, col_cdf[r], np.arange(W + 1)) for u, r in zip(uv[:, 0], row, strict=True)])
    return np.stack([x_pixels, y_pixels], 1) * pixel


def cluster_parents(density: np.ndarray, n: int, domain: tuple[float, float], children: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(parent of each of n points (n, 2), local mean spacing sqrt(1 / intensity) there (n,)): ``n / children``
    density-proportional parents, each point's drawn uniformly among them (a cluster process's first stage)."""
    parents = random_stipple(density, max(1, round(n / children)), domain, rng)
    owner = rng.integers(len(parents), size=n)
    spacing = local_r_max(density, n, domain, parents) * math.sqrt(SQRT3 / 2.0)
    return parents[owner], spacing[owner]


def _clipped(xy: np.ndarray, domain: tuple[float, float]) -> np.ndarray:
    """``xy`` with the points leaving the domain clipped onto it."""
    return np.clip(xy, 0.0, np.nextafter(np.asarray(domain), 0.0))


def thomas_clusters(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """n points of a Thomas process: ``n / 16`` density-proportional parents, each point offset from its parent by
    a Gaussian of :data:`CLUSTER_STD_SPACINGS` local mean spacings; points leaving the domain are clipped onto it."""
    parent, spacing = cluster_parents(density, n, domain, CLUSTER_POINTS, rng)
    return _clipped(parent + rng.normal(size=(n, 2)) * (CLUSTER_STD_SPACINGS * spacing)[:, None], domain)


def matern_clusters(children: float, radius_spacings: float) -> Method:
    """A Matérn cluster process: ``n / children`` density-proportional parents, each point uniform in a disc of
    ``radius_spacings`` local mean spacings around its parent (drawn uniformly among the parents); points leaving the
    domain are clipped onto it."""
    def stipple(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
        parent, spacing = cluster_parents(density, n, domain, children, rng)
        radius = radius_spacings * spacing * np.sqrt(rng.random(n))
        angle = rng.uniform(0.0, 2.0 * math.pi, n)
        return _clipped(parent + radius[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1), domain)

    stipple.__name__ = f"matern_clusters_{children:g}_{radius_spacings:g}"
    stipple.__doc__ = (f"n points of a Matérn cluster process, {children:g} points per parent on average, uniform in "
                       f"discs of {radius_spacings:g} local mean spacings (:func:`matern_clusters`).")
    return stipple


def _grid_shape(density: np.ndarray, n: int, domain: tuple[float, float]) -> tuple[int, int]:
    """(columns, rows) of the raster stipplers' grid: about ``n / mean density`` nearly square pixels over ``domain``."""
    w, h = domain
    columns = max(1, round(math.sqrt(n / max(float(np.mean(density)), 1e-6) * w / h)))
    return columns, max(1, round(columns * h / w))


def floyd_steinberg(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """About n points: Floyd-Steinberg dithering (Pillow) of the density on a grid of ``n / mean density`` pixels,
    a point at the centre of each inked pixel. ``rng`` is unused (the dither is deterministic)."""
    from PIL import Image

    columns, rows = _grid_shape(density, n, domain)
    grey = Image.fromarray(np.round(255 * (1 - np.clip(density, 0, 1))).astype(np.uint8)).resize((columns, rows), Image.Resampling.BOX)
    inked = np.asarray(grey.convert("1", dither=Image.Dither.FLOYDSTEINBERG)) == 0
    row, col = np.nonzero(inked)
    return (np.stack([col, row], 1) + 0.5) * (domain[0] / columns)


# --- raster stipplers: a point at each inked pixel of a grid of about n / mean density pixels ----------------
# Error-diffusion kernels: (row offset, column offset, weight) of the error passed on, weights summing to 1.
ED_KERNELS: dict[str, tuple[tuple[int, int, float], ...]] = {
    "floyd_steinberg": tuple((r, c, w / 16) for r, c, w in ((0, 1, 7), (1, -1, 3), (1, 0, 5), (1, 1, 1))),
    "jarvis": tuple((r, c, w / 48) for r, c, w in ((0, 1, 7), (0, 2, 5), (1, -2, 3), (1, -1, 5), (1, 0, 7), (1, 1, 5),
                                                   (1, 2, 3), (2, -2, 1), (2, -1, 3), (2, 0, 5), (2, 1, 3), (2, 2, 1))),
    "sierra": tuple((r, c, w / 32) for r, c, w in ((0, 1, 5), (0, 2, 3), (1, -2, 2), (1, -1, 4), (1, 0, 5), (1, 1, 4),
                                                   (1, 2, 2), (2, -1, 2), (2, 0, 3), (2, 1, 2))),
}


def ink_grid(density: np.ndarray, n: int, domain: tuple[float, float]) -> tuple[np.ndarray, tuple[float, float]]:
    """(density area-resampled to a grid of about ``n / mean density`` (nearly square) pixels, pixel (width, height)
    in domain units, the grid covering the domain exactly): its total ink is about n pixels, so a dither of it
    inks about n pixels."""
    from PIL import Image

    w, h = domain
    columns, rows = _grid_shape(density, n, domain)
    image = Image.fromarray(np.asarray(np.clip(density, 0, 1), np.float32), mode="F")
    grid = np.asarray(image.resize((columns, rows), Image.Resampling.BOX), np.float64)
    return np.clip(grid, 0.0, 1.0), (w / columns, h / rows)


def pixel_points(inked: np.ndarray, pixel: tuple[float, float], rng: np.random.Generator | None = None, jitter: float = 0.0) -> np.ndarray:
    """(k, 2) positions of the inked pixels' centres (optionally moved uniformly by up to ``jitter`` pixels each way)."""
    row, col = np.nonzero(inked)
    xy = np.stack([col, row], 1) + 0.5
    if jitter and rng is not None:
        xy = xy + (rng.random(xy.shape) - 0.5) * (2.0 * jitter)
    return xy * np.asarray(pixel)


def diffuse_error(grid: np.ndarray, kernel: tuple[tuple[int, int, float], ...], serpentine: bool = False) -> np.ndarray:
    """(H, W) bool: error-diffusion dither of ``grid`` (ink in [0, 1]) with ``kernel``; threshold 0.5; raster
    order, or serpentine (alternate rows right to left, the kernel mirrored)."""
    H, W = grid.shape
    pad = 2
    work = np.zeros((H + pad, W + 2 * pad))
    work[:H, pad:pad + W] = grid
    inked = np.zeros((H, W), bool)
    for row in range(H):
        backward = serpentine and row % 2 == 1
        line = work[row]
        for col in (range(W - 1, -1, -1) if backward else range(W)):
            value = line[col + pad]
            on = value >= 0.5
            inked[row, col] = on
            error = value - (1.0 if on else 0.0)
            for dr, dc, weight in kernel:
                work[row + dr, col + pad + (-dc if backward else dc)] += error * weight
    return inked


def _error_diffusion(kernel: str, serpentine: bool = False) -> Method:
    def stipple(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
        grid, pixel = ink_grid(density, n, domain)
        return pixel_points(diffuse_error(grid, ED_KERNELS[kernel], serpentine), pixel)

    stipple.__name__ = f"{kernel}{'_serpentine' if serpentine else ''}_error_diffusion"
    stipple.__doc__ = (f"About n points: {kernel} error diffusion ({'serpentine' if serpentine else 'raster'} scan) of the density "
                       "on the grid of :func:`ink_grid`, a point at each inked pixel's centre. ``rng`` is unused.")
    return stipple


jarvis_error_diffusion = _error_diffusion("jarvis")
sierra_serpentine_error_diffusion = _error_diffusion("sierra", serpentine=True)


def jittered_floyd_steinberg(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """:func:`floyd_steinberg` (serpentine here, own code) with each point moved uniformly within +-0.35 pixel."""
    grid, pixel = ink_grid(density, n, domain)
    return pixel_points(diffuse_error(grid, ED_KERNELS["floyd_steinberg"], serpentine=True), pixel, rng, jitter=0.35)


def bayer_matrix(order: int) -> np.ndarray:
    """(2^order, 2^order) Bayer threshold matrix in (0, 1): (index + 0.5) / size^2."""
    matrix = np.zeros((1, 1))
    for _ in range(order):
        matrix = np.block([[4 * matrix, 4 * matrix + 2], [4 * matrix + 3, 4 * matrix + 1]])
    return (matrix + 0.5) / matrix.size


def bayer_dither(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """About n points: ordered dithering (8 x 8 Bayer matrix, at a random offset from ``rng``) of the density on the
    grid of :func:`ink_grid`, a point at each inked pixel's centre."""
    grid, pixel = ink_grid(density, n, domain)
    H, W = grid.shape
    dy, dx = rng.integers(8, size=2)
    threshold = np.roll(bayer_matrix(3), (int(dy), int(dx)), axis=(0, 1))
    threshold = np.tile(threshold, (H // 8 + 1, W // 8 + 1))[:H, :W]
    return pixel_points(grid > threshold, pixel)


def _supersample(density: np.ndarray, n: int) -> int:
    """The supersampling factor giving at least 8 pixels per point (the Lloyd stipplers' centroids live on the grid)."""
    return max(1, math.ceil(math.sqrt(8 * n / np.size(density))))


def _lloyd_iterations(iterations: int) -> Method:
    def stipple(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
        return lloyd_stipple(density, n, domain, iterations=iterations, seed=int(rng.integers(2**31)),
                             supersample=_supersample(density, n))

    stipple.__name__ = f"lloyd_{iterations}"
    stipple.__doc__ = f":func:`lloyd_stipple` with {iterations} iterations on the density supersampled to >= 8 pixels per point."
    return stipple


lloyd_few = _lloyd_iterations(4)
lloyd_many = _lloyd_iterations(150)


def capacity_voronoi(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """:func:`capacity_lloyd_stipple` (equal-ink power cells) with 30 iterations on the density supersampled to
    >= 8 pixels per point. FROZEN: test set only (:data:`FROZEN_METHODS`)."""
    dens = np.asarray(density, np.float64)
    supersample = _supersample(dens, n)
    if supersample > 1:
        dens = np.kron(dens, np.ones((supersample, supersample)))
    return capacity_lloyd_stipple(dens, n, domain, iterations=30, seed=int(rng.integers(2**31)))[0]


_lloyd = _lloyd_iterations(40)

LATTICE_JITTER = {"near": 0.05, "jittered": 0.2}  # Gaussian displacement per axis, lattice spacings


def rotated_lattice(n: int, hexagonal: bool, jitter: float, rng: np.random.Generator) -> np.ndarray:
    """(k, 2) points in the unit square, k about n: a square or hexagonal lattice of n points per unit area at a
    uniform random rotation and offset, each point moved by a Gaussian of ``jitter`` spacings per axis."""
    spacing = r_max(n, 1.0) if hexagonal else 1.0 / math.sqrt(n)
    row_step = spacing * (SQRT3 / 2.0 if hexagonal else 1.0)
    reach = math.ceil(SQRT2 / min(spacing, row_step)) + 2  # lattice indices covering the square at any rotation
    i, j = np.meshgrid(np.arange(-reach, reach + 1), np.arange(-reach, reach + 1))
    x = (i + (0.5 * (j % 2) if hexagonal else 0.0)) * spacing
    y = j * row_step
    angle = rng.uniform(0.0, math.pi)
    cos, sin = math.cos(angle), math.sin(angle)
    xy = np.stack([cos * x - sin * y, sin * x + cos * y], -1).reshape(-1, 2) + 0.5 + rng.random(2) * spacing
    xy = xy + rng.normal(size=xy.shape) * (jitter * spacing)
    return xy[np.all((xy >= 0.0) & (xy < 1.0), axis=1)]


def _lattice(hexagonal: bool, jitter: str) -> Method:
    def stipple(density: np.ndarray, n: int, domain: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
        return warp_by_density(rotated_lattice(n, hexagonal, LATTICE_JITTER[jitter], rng), density, domain)

    shape = "hexagonal" if hexagonal else "square"
    stipple.__name__ = f"{shape}_lattice_{jitter}"
    stipple.__doc__ = (f"About n points: a {shape} lattice at a random rotation and offset (:func:`rotated_lattice`, "
                       f"jitter {LATTICE_JITTER[jitter]} spacings), mapped to the density by :func:`warp_by_density`.")
    return stipple


METHODS: dict[str, Method] = {
    "random": random_stipple,
    "lloyd": _lloyd,
    "poisson_disk": variable_poisson_disk,
    "jitter": warped_jitter,
    "clusters": thomas_clusters,
    "floyd_steinberg": floyd_steinberg,
    "jarvis": jarvis_error_diffusion,
    "floyd_steinberg_jitter": jittered_floyd_steinberg,
    "bayer": bayer_dither,
    "lloyd_few": lloyd_few,
    "lloyd_many": lloyd_many,
    "lattice_square": _lattice(False, "near"),
    "lattice_hex": _lattice(True, "near"),
    "lattice_square_jitter": _lattice(False, "jittered"),
    "lattice_hex_jitter": _lattice(True, "jittered"),
    "matern_tight": matern_clusters(6, 0.45),
    "matern_dense": matern_clusters(12, 0.85),
    "matern_loose": matern_clusters(6, 0.85),
    "matern_wide": matern_clusters(4, 1.6),
}
FROZEN_METHODS: dict[str, Method] = {
    "sierra_serpentine": sierra_serpentine_error_diffusion,
    "capacity_voronoi": capacity_voronoi,
}
"""The frozen test set's stipplers (docs/evaluation.md): never in :data:`METHODS` or :data:`LABELS`; the training-pair
code (:func:`data_gen.pairs.other_methods_setting`, :func:`data_gen.pairs.other_method_points`) refuses them."""
DEFAULT_METHODS = ("random", "lloyd", "poisson_disk", "jitter", "clusters")  # other_methods.methods when none are given
LABELS: dict[str, str | tuple[float, float]] = {
    "random": "white", "lloyd": "blue", "poisson_disk": "blue", "jitter": "step", "clusters": "red",  # jitter: merged into step
    # measured (bench/stippler_labels.py --seeds 2, shipped palette): the mean a, b decoded from each method's stationary samples
    "floyd_steinberg": (24.4, -48.1), "jarvis": (25.2, -38.0), "floyd_steinberg_jitter": (23.6, -40.2),
    "bayer": (24.5, -45.1), "lloyd_few": (18.4, -55.5), "lloyd_many": (16.8, -56.6),
    "lattice_square": (-43.6, -43.9), "lattice_hex": (-25.6, -56.9),
    "lattice_square_jitter": (23.5, -43.3), "lattice_hex_jitter": (24.5, -43.2),
    "matern_tight": (-99.7, 21.4), "matern_dense": (-78.9, 45.9), "matern_loose": (51.3, 35.8), "matern_wide": (14.0, 3.0),
}
"""Training label of each method: a preset name of the pairs' palette, or the (a, b) measured by decoding the method's
stationary samples with the shipped palette (the module docstring's table)."""
