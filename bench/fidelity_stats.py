"""Point-pattern statistics for the fidelity bench, written independently of the synthesiser.

Nothing here imports ``synthesis``: these estimators are the yardstick the
synthesiser is measured with, so they must not share its code or its choices
(kernel, radii, edge handling). Conventions:

* A pattern is ``xy`` (n, 2) in the domain ``[0, w] x [0, h]`` (y down, but no
  statistic here cares). ``periodic=True`` means the domain is a torus (the
  reference generators); otherwise it is a bounded window.
* Distances are in units of ``r_max = 2 sqrt(A / (2 sqrt(3) n))``, the spacing
  of the densest packing (hexagonal lattice) of n points in area A, or of the
  *local* r_max where the intensity varies: ``lambda(x) = n density(x) /
  (mean density * A)`` and ``local r_max = 2 / sqrt(2 sqrt(3) lambda(x))``.

Statistics: a fine pair correlation function (translation edge correction,
Gaussian kernel, annulus normalisation so that it is finite and unbiased from
r = 0), nearest-neighbour statistics (stacked fraction, minimum, coefficient
of variation), largest empty circles (Delaunay circumcircles), strip density
profiles across edges and along the border, density PSNR against a target
after a Gaussian blur. The reference stipplers (weighted Lloyd, its stratified
start, scipy's Poisson-disk) come from :mod:`data_gen.stipplers` and are
re-exported here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.spatial import Delaunay, cKDTree
from scipy.special import ndtr

from data_gen.stipplers import lloyd_stipple, poisson_disk, r_max, stratified_start  # noqa: F401 - re-exported (see the end)

SQRT3 = math.sqrt(3.0)
STACKED = 0.05  # NN below this many local r_max counts as a stacked point


def r_max_of_intensity(intensity: np.ndarray | float) -> np.ndarray:
    """Local r_max for an intensity (points per unit area)."""
    return 2.0 / np.sqrt(2.0 * SQRT3 * np.maximum(intensity, 1e-12))


# --------------------------------------------------------------------------- density


@dataclass
class Intensity:
    """Target intensity of n points on a density raster covering ``[0, w] x [0, h]``.

    ``density`` is (H, W) in [0, 1], row 0 at y = 0; pixels are square, of side
    ``max(w, h) / max(H, W)``, as in the maps. Lookup is nearest-pixel.
    """

    density: np.ndarray
    domain: tuple[float, float]
    n: int
    floor: float = 1e-3  # density below this reads as this (keeps local r_max finite)

    @classmethod
    def constant(cls, n: int, domain: tuple[float, float] = (1.0, 1.0)) -> Intensity:
        return cls(np.ones((1, 1)), domain, n)

    @property
    def area(self) -> float:
        return self.domain[0] * self.domain[1]

    def density_at(self, xy: np.ndarray) -> np.ndarray:
        H, W = self.density.shape
        w, h = self.domain
        col = np.clip((np.asarray(xy)[..., 0] / w * W).astype(np.int64), 0, W - 1)
        row = np.clip((np.asarray(xy)[..., 1] / h * H).astype(np.int64), 0, H - 1)
        return self.density[row, col]

    def intensity_at(self, xy: np.ndarray) -> np.ndarray:
        mean = float(self.density.mean())
        return self.n * np.maximum(self.density_at(xy), self.floor) / (mean * self.area)

    def local_r_max(self, xy: np.ndarray) -> np.ndarray:
        return r_max_of_intensity(self.intensity_at(xy))


# --------------------------------------------------------------------------- PCF


def pcf(xy: np.ndarray, domain: tuple[float, float] = (1.0, 1.0), periodic: bool = False,
        r_hi: float = 2.5, bins: int = 101, sigma: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Fine pair correlation function of a stationary pattern.

    ``g(r) = A / (n (n - 1)) * sum_{i != j} k(r - d_ij) e_ij / a(r)`` with
    ``k`` a Gaussian of width ``sigma`` (in r_max), ``e_ij = A / |W ∩ (W + x_i - x_j)|``
    Ohser's translation edge correction (1 on a torus, with minimum-image
    distances), and ``a(r) = 2 pi * int_0^inf s k(r - s) ds = 2 pi (r Phi(r/sigma)
    + sigma phi(r/sigma))`` the kernel-weighted annulus area, so a Poisson
    pattern reads 1 at every r including r = 0, and stacked pairs show as a peak
    at r = 0. Returns (r in r_max units on [0, r_hi], g).
    """
    xy = np.asarray(xy, np.float64)
    n = len(xy)
    w, h = domain
    area = w * h
    unit = r_max(n, area)
    r = np.linspace(0.0, r_hi, bins)
    reach = (r_hi + 5 * sigma) * unit
    if periodic:
        tree = cKDTree(np.mod(xy, [w, h]), boxsize=[w, h])
    else:
        tree = cKDTree(xy)
    pairs = tree.query_pairs(reach, output_type="ndarray")
    d = xy[pairs[:, 0]] - xy[pairs[:, 1]]
    if periodic:
        d -= np.round(d / [w, h]) * [w, h]
        weight = np.ones(len(d))
    else:
        weight = area / ((w - np.abs(d[:, 0])) * (h - np.abs(d[:, 1])))
    dist = np.hypot(d[:, 0], d[:, 1]) / unit
    g = np.zeros(bins)
    # each unordered pair counts twice (i, j) and (j, i); accumulate in chunks of radii
    for start in range(0, bins, 16):
        rr = r[start:start + 16, None]
        kernel = np.exp(-0.5 * ((rr - dist[None]) / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
        g[start:start + 16] = 2.0 * (kernel * weight[None]).sum(axis=1)
    annulus = 2 * math.pi * (r * ndtr(r / sigma) + sigma * np.exp(-0.5 * (r / sigma) ** 2) / math.sqrt(2 * math.pi))
    # distances are in r_max units: annulus area in r_max^2 -> multiply by unit^2
    g *= area / (n * (n - 1)) / (annulus * unit**2)
    return r, g


def pcf_distance(g1: np.ndarray, g2: np.ndarray) -> float:
    """L2 (root-mean-square over the radius grid) distance between two PCFs on the same grid."""
    return float(np.sqrt(np.mean((np.asarray(g1) - np.asarray(g2)) ** 2)))


# --------------------------------------------------------------------------- nearest neighbours


def nearest_neighbours(xy: np.ndarray, domain: tuple[float, float] = (1.0, 1.0), periodic: bool = False) -> np.ndarray:
    """Distance from each point to its nearest other point (minimum image on a torus)."""
    xy = np.asarray(xy, np.float64)
    tree = cKDTree(np.mod(xy, domain), boxsize=domain) if periodic else cKDTree(xy)
    d, _ = tree.query(np.mod(xy, domain) if periodic else xy, k=2)
    return d[:, 1]


def border_distance(xy: np.ndarray, domain: tuple[float, float]) -> np.ndarray:
    w, h = domain
    return np.minimum.reduce([xy[:, 0], w - xy[:, 0], xy[:, 1], h - xy[:, 1]])


def nn_stats(xy: np.ndarray, intensity: Intensity, periodic: bool = False) -> dict:
    """NN distances in local r_max units.

    * ``stacked_fraction``: share of points whose NN is below 0.05 local r_max (all points);
    * ``min_nn``: the smallest NN (all points);
    * ``nn_cv``, ``nn_mean``: coefficient of variation and mean of NN over the points whose
      NN is shorter than their distance to the border (minus-sampling border correction;
      all points on a torus), so bounded and periodic patterns compare.
    """
    xy = np.asarray(xy, np.float64)
    raw = nearest_neighbours(xy, intensity.domain, periodic)
    nn = raw / intensity.local_r_max(xy)
    keep = np.ones(len(xy), bool) if periodic else raw < border_distance(xy, intensity.domain)
    kept = nn[keep]
    return {"stacked_fraction": float(np.mean(nn < STACKED)), "stacked_count": int(np.sum(nn < STACKED)),
            "min_nn": float(nn.min()), "nn_mean": float(kept.mean()), "nn_cv": float(kept.std() / kept.mean())}


# --------------------------------------------------------------------------- empty circles


def _circumcircles(points: np.ndarray, simplices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b, c = points[simplices[:, 0]], points[simplices[:, 1]], points[simplices[:, 2]]
    b = b - a
    c = c - a
    d = 2.0 * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0])
    ok = np.abs(d) > 1e-18
    d = np.where(ok, d, 1.0)
    bb, cc = (b**2).sum(1), (c**2).sum(1)
    ux = (c[:, 1] * bb - b[:, 1] * cc) / d
    uy = (b[:, 0] * cc - c[:, 0] * bb) / d
    centre = a + np.stack([ux, uy], 1)
    radius = np.where(ok, np.hypot(ux, uy), 0.0)
    return centre, radius


_DISK = None


def _disk_samples(k: int = 61) -> np.ndarray:
    """Sunflower points covering the unit disk (centre included)."""
    global _DISK
    if _DISK is None or len(_DISK) != k:
        i = np.arange(k) + 0.5
        rho = np.sqrt(i / k)
        theta = i * math.pi * (3 - math.sqrt(5))
        _DISK = np.concatenate([[[0.0, 0.0]], np.stack([rho * np.cos(theta), rho * np.sin(theta)], 1)])
    return _DISK


def empty_circles(xy: np.ndarray, intensity: Intensity, periodic: bool = False, min_density: float = 0.15,
                  hole: float = 1.0, candidates: int = 3000) -> dict:
    """Largest empty circles: Delaunay circumcircles (centred on Voronoi vertices).

    A circle of radius R is measured in local r_max units through its expected
    count: ``E = int_disk lambda``, equivalent radius ``rho = sqrt(E sqrt(3) / (2 pi))``
    (= R / r_max for a constant intensity). Counted only where the circle lies
    inside the domain (bounded windows) and the density is >= ``min_density`` at
    every sample of the disk. Returns the largest ``rho``, where it is, and the
    number of distinct holes with ``rho > hole`` (non-maximum suppression: a
    circle whose centre lies inside a larger counted one is the same hole).
    """
    xy = np.asarray(xy, np.float64)
    w, h = intensity.domain
    if periodic:
        base = np.mod(xy, [w, h])
        margin = 0.25 * max(w, h)
        tiles = [base]
        for dx in (-w, 0.0, w):
            for dy in (-h, 0.0, h):
                if dx == 0.0 and dy == 0.0:
                    continue
                shifted = base + [dx, dy]
                inside = ((shifted[:, 0] > -margin) & (shifted[:, 0] < w + margin)
                          & (shifted[:, 1] > -margin) & (shifted[:, 1] < h + margin))
                tiles.append(shifted[inside])
        pts = np.concatenate(tiles)
    else:
        pts = xy
    tri = Delaunay(pts)
    centre, radius = _circumcircles(pts, tri.simplices)
    inside = (centre[:, 0] >= 0) & (centre[:, 0] < w) & (centre[:, 1] >= 0) & (centre[:, 1] < h)
    if not periodic:
        inside &= (centre[:, 0] - radius >= 0) & (centre[:, 0] + radius <= w)
        inside &= (centre[:, 1] - radius >= 0) & (centre[:, 1] + radius <= h)
    inside &= intensity.density_at(centre) >= min_density
    centre, radius = centre[inside], radius[inside]
    if len(radius) == 0:
        return {"largest": float("nan"), "holes": 0, "largest_at": None, "largest_radius_abs": float("nan")}
    rough = radius / intensity.local_r_max(centre)
    order = np.argsort(-rough)[:candidates]
    centre, radius = centre[order], radius[order]
    samples = centre[:, None, :] + radius[:, None, None] * _disk_samples()[None]
    samples = np.mod(samples, [w, h]) if periodic else samples
    dens = intensity.density_at(samples)
    lam = intensity.intensity_at(samples).mean(axis=1)
    expected = lam * math.pi * radius**2
    rho = np.sqrt(expected * SQRT3 / (2 * math.pi))
    valid = dens.min(axis=1) >= min_density
    centre, radius, rho = centre[valid], radius[valid], rho[valid]
    if len(rho) == 0:
        return {"largest": float("nan"), "holes": 0, "largest_at": None, "largest_radius_abs": float("nan")}
    order = np.argsort(-rho)
    centre, radius, rho = centre[order], radius[order], rho[order]
    accepted: list[int] = []
    for i in np.nonzero(rho > hole)[0]:
        if all(np.hypot(*(centre[i] - centre[j])) > radius[j] for j in accepted):
            accepted.append(int(i))
    return {"largest": float(rho[0]), "holes": len(accepted), "largest_at": [float(centre[0, 0]), float(centre[0, 1])],
            "largest_radius_abs": float(radius[0])}


# --------------------------------------------------------------------------- strip profiles


def strip_profile(signed: np.ndarray, expected_per_unit: float, unit: float, lo: float, hi: float,
                  width: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Counts of points in strips ``width`` r_max wide of a signed distance (r_max units), relative
    to the expected count; ``expected_per_unit`` is the expected number of points per unit of the
    distance coordinate (intensity times the strips' length). Returns (strip centres, ratios)."""
    edges = np.arange(lo, hi + 1e-9, width)
    counts, _ = np.histogram(signed / unit, bins=edges)
    expected = expected_per_unit * width * unit
    return 0.5 * (edges[:-1] + edges[1:]), counts / expected


def border_profile(xy: np.ndarray, domain: tuple[float, float], n: int, depth: float = 3.0,
                   width: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Counts in rings ``width`` r_max wide at distance [k width, (k+1) width) from the border of a
    constant-intensity rectangle, relative to n * ring area / A (all four sides, corners included)."""
    w, h = domain
    unit = r_max(n, w * h)
    d = border_distance(np.asarray(xy, np.float64), domain) / unit
    edges = np.arange(0.0, depth + 1e-9, width)
    counts, _ = np.histogram(d, bins=edges)
    a = edges * unit
    inner = (w - 2 * a) * (h - 2 * a)
    ring = inner[:-1] - inner[1:]
    return 0.5 * (edges[:-1] + edges[1:]), counts / (n * ring / (w * h))


# --------------------------------------------------------------------------- density PSNR


def rasterise(xy: np.ndarray, shape: tuple[int, int], domain: tuple[float, float]) -> np.ndarray:
    """Point mass per pixel of an (H, W) raster of the domain, splatted bilinearly (tent) between
    the four nearest pixel centres (mass beyond the outer centres goes to the border pixel).

    Binning each point into its pixel (a box filter) aliases the harmonics of a regular
    pattern into a low-frequency moiré of several per cent that no blur removes; the tent's
    spectrum (sinc squared) suppresses it."""
    H, W = shape
    w, h = domain
    pixel = max(w, h) / max(H, W)
    u = np.asarray(xy)[:, 0] / pixel - 0.5
    v = np.asarray(xy)[:, 1] / pixel - 0.5
    i0, j0 = np.floor(v).astype(np.int64), np.floor(u).astype(np.int64)
    fv, fu = v - i0, u - j0
    out = np.zeros(H * W)
    for di, wi in ((0, 1 - fv), (1, fv)):
        for dj, wj in ((0, 1 - fu), (1, fu)):
            i = np.clip(i0 + di, 0, H - 1)
            j = np.clip(j0 + dj, 0, W - 1)
            out += np.bincount(i * W + j, wi * wj, minlength=H * W)
    return out.reshape(H, W)


def density_psnr(xy: np.ndarray, density: np.ndarray, domain: tuple[float, float], blur_spacings: float) -> float:
    """PSNR (dB) of the points' density against a target density after a Gaussian blur.

    Both the point counts per pixel and the target density are normalised to mean
    1 (equal mass), blurred by a Gaussian of ``blur_spacings`` mean spacings
    (``sqrt(A / n)``; zero padding outside the domain for both, so a pattern that keeps its density
    up to the border matches; a reflecting boundary would turn the border rows of a regular
    pattern into a doubled or missing row and dominate the error), and compared:
    ``10 log10(max(target)^2 / MSE)``.
    """
    H, W = density.shape
    n = len(xy)
    w, h = domain
    pixel = max(w, h) / max(H, W)
    sigma = blur_spacings * math.sqrt(w * h / n) / pixel
    points = rasterise(xy, (H, W), domain)
    points = points / points.mean()
    target = density.astype(np.float64) / density.mean()
    points = gaussian_filter(points, sigma, mode="constant")
    target = gaussian_filter(target, sigma, mode="constant")
    mse = float(np.mean((points - target) ** 2))
    return float(10 * np.log10(target.max() ** 2 / mse))


# --------------------------------------------------------------------------- references
# The weighted Lloyd stippler, its stratified start and scipy's Poisson-disk sampling live in
# data_gen/stipplers.py (numpy, scipy and Pillow only, no synthesis import), which the network's
# training pairs and evaluation use too; they and r_max are imported at the top.
