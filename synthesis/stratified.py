"""Density-matched starting points: stratified along a Hilbert curve, or independent.

:class:`StratifiedSampler` cuts the map into cells, orders them along a Hilbert
curve, and places point i at the cumulative density mass ``(i + U_i) / n`` (one
jittered stratum per point): the density is matched locally at every scale
and there are no holes or clumps. :func:`random_points` draws independent
points with probability proportional to the density (an inhomogeneous Poisson
start). Both return (n, 2) float64 positions in ``[0, w] x [0, h]``.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numba
import numpy as np

from synthesis.labmap import pixels_of

MAX_ORDER = 11  # at most 2048 x 2048 cells
CELLS_PER_POINT = 4  # at the densest cell, at least this many cells per point where MAX_ORDER allows


def hilbert_index(order: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Position along the Hilbert curve of cells (x, y) (int arrays in [0, 2^order)) of a 2^order grid."""
    side = 1 << order
    x, y = x.astype(np.int64).copy(), y.astype(np.int64).copy()
    d = np.zeros_like(x)
    s = side >> 1
    while s > 0:
        rx = (x & s) > 0
        ry = (y & s) > 0
        d += s * s * ((3 * rx.astype(np.int64)) ^ ry.astype(np.int64))
        flip = ~ry & rx
        x[flip], y[flip] = side - 1 - x[flip], side - 1 - y[flip]
        swap = ~ry
        x[swap], y[swap] = y[swap], x[swap]
        s >>= 1
    return d


@numba.njit(cache=True)
def _hilbert_cells(order, out):  # pragma: no cover - jitted
    side = 1 << order
    for d in range(side * side):  # the curve's d-th cell: its quadrant, two bits of d a level, from the finest up
        t, x, y, s = d, 0, 0, 1
        while s < side:
            rx = 1 & (t >> 1)
            ry = 1 & (t ^ rx)
            if ry == 0:
                if rx == 1:
                    x, y = s - 1 - x, s - 1 - y
                x, y = y, x
            x += s * rx
            y += s * ry
            t >>= 2
            s <<= 1
        out[d] = y * side + x


@lru_cache(maxsize=2)
def hilbert_cells(order: int) -> np.ndarray:
    """(4^order,) int32 cells ``row x 2^order + column`` of a 2^order grid in their order along the Hilbert curve.

    The inverse of :func:`hilbert_index` (equal to ``argsort`` of it over every cell, without the sort; numba, one pass
    a cell: 2^10 a side, one thread, about 0.02 s against 0.15 s for the same loop over numpy arrays), computed
    once per order: the start's sampler and the window sampler use the same grid (at 100k points, 2^10 a side).
    """
    cells = np.empty(1 << (2 * order), np.int32)  # kept: int32 halves it (2^11 a side: 17 MB)
    _hilbert_cells(order, cells)
    cells.flags.writeable = False  # shared by every caller
    return cells


def spatial_order(xy: np.ndarray, domain: tuple[float, float], order: int = 10) -> np.ndarray:
    """(n,) permutation sorting points (n, 2) in ``[0, w] x [0, h]`` along a Hilbert curve of 2^order cells per side.

    Points close in space end up close in memory (fewer cache misses in neighbour loops).
    """
    side = 1 << order
    cells = np.clip((np.asarray(xy) / max(domain) * side).astype(np.int64), 0, side - 1)
    return np.argsort(hilbert_index(order, cells[:, 0], cells[:, 1]), kind="stable")


def _cell_grid(density: np.ndarray, side_px: int, domain: tuple[float, float], n: int,
               extent: float = 1.0) -> tuple[int, np.ndarray]:
    """Order of a 2^order grid over the square ``[0, extent]^2`` (extent >= 1, the unit square's side) and its cells'
    mass (2^order, 2^order): density x the cell's share inside the domain (0 outside it)."""
    peak = float(density.max()) / max(float(density.mean()), 1e-12)
    area = domain[0] * domain[1]
    wanted = CELLS_PER_POINT * n * peak / area  # the same order for any extent (the window sampler shares its curve)
    order = min(MAX_ORDER, max(4, math.ceil(0.5 * math.log2(max(wanted, 1.0)))))
    side = 1 << order
    # each cell's mass is the exact integral of the density, constant on each pixel (as the tone term and
    # random_points read it), over the cell's part inside the domain: the differences of the density's summed-area
    # table, bilinear within a pixel (exact there), at the cells' corners. Before, the density sampled bilinearly at the
    # cell's centre spread a sharp density step over a pixel: the start put 1.35 of the expected density in the first
    # 0.5 r_max of the light side of a blue L 15 | L 76 edge (6 seeds), 0.81 on the dark side (docs/synthesis.md). Cells
    # straddling the domain's edge count their part inside it: a domain thinner than a cell (1 x 10000 px) has mass
    table = np.zeros((density.shape[0] + 1, density.shape[1] + 1))
    np.cumsum(np.cumsum(density, axis=0, dtype=np.float64), axis=1, out=table[1:, 1:])
    stencils = []
    for axis, size in enumerate(density.shape[::-1]):  # x (columns), then y (rows): the corners in pixels
        at = np.minimum(np.arange(side + 1) / side * extent, domain[axis]) * side_px
        at = np.clip(at, 0.0, size)
        lower = np.minimum(at.astype(np.int64), max(size - 1, 0))
        stencils.append((lower, lower + 1, at - lower))
    (c0, c1, tx), (r0, r1, ty) = stencils
    across = table[:, c0] * (1.0 - tx) + table[:, c1] * tx  # (H + 1, side + 1)
    corner = across[r0] * (1.0 - ty[:, None]) + across[r1] * ty[:, None]  # (side + 1, side + 1)
    mass = corner[1:, 1:] - corner[:-1, 1:] - corner[1:, :-1] + corner[:-1, :-1]
    return order, np.maximum(mass, 0.0) * (side / (extent * side_px)) ** 2


class StratifiedSampler:
    """Draws of points stratified along a Hilbert curve through a density (H, W) >= 0, not all 0.

    The cell grid is sized for up to ``n`` points; the curve and the cumulative
    mass are computed once, so repeated draws cost O(count log cells).

    With ``rng``, the grid spans a square 1-2 times the map's side (random; the cells beyond the domain hold no mass;
    at least 1 cell per point instead of 4).
    Over the map itself, a stratum of a uniform square map of 4^k points is a block of the grid's cells, the start a
    jittered square grid, and the leashed optimisation turned it into a square lattice (blue, 4,096 points: rows of
    points parallel to the border, strips 0.54-1.49 of the expected density up to the map's centre); a random extent
    makes the strata's shapes vary. (Jittering each point over two strata instead broke the lattice but left the
    start's holes 13 % wider and the result 3 % of its points closer than 0.7 r_max, against 1-2 %.)
    """

    def __init__(self, density: np.ndarray, side_px: int, domain: tuple[float, float], n: int,
                 rng: np.random.Generator | None = None):
        self.extent = 1.0 if rng is None else 1.0 + float(rng.random())
        order, cells = _cell_grid(density, side_px, domain, n, self.extent)
        self.side, self.domain, self.density, self.side_px = 1 << order, domain, density, side_px
        self.along = hilbert_cells(order)
        self.mass = np.cumsum(cells.reshape(-1)[self.along])

    def draw(self, count: int, rng: np.random.Generator) -> np.ndarray:
        """(count, 2) points, one per stratum of density mass (jittered within it and within its cell, with the
        density: see :meth:`_within`)."""
        strata = (np.arange(count) + rng.random(count)) / count * self.mass[-1]
        cell = self.along[np.minimum(np.searchsorted(self.mass, strata, side="right"), len(self.along) - 1)]
        row, col = np.divmod(cell, self.side)
        lo = np.stack([col, row], axis=1) * (self.extent / self.side)
        extent = np.minimum(lo + self.extent / self.side, np.asarray(self.domain)) - lo  # the cell's part inside the domain
        return np.minimum(self._within(lo, extent, rng), np.array(self.domain) * (1 - 1e-9))

    def _within(self, lo: np.ndarray, extent: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(k, 2) one point in each cell ``[lo, lo + extent]`` (k, 2), with the density (constant on each pixel) across
        the pixels the cell touches: uniform, then rejected with probability 1 - density / the largest density at the
        cell's corners (exact for cells that span at most two pixels a side; the start's span at most one unless the map
        has more pixels than the grid cells, where a step inside a cell is finer than the points' spacing). Cells of
        one density draw nothing more (a map of one density keeps its random stream). A uniform jitter put the mass of
        the cell's dark part on its light part too: 1.25 of the expected density in the light side's first 0.5 r_max at
        a blue L 15 | L 76 edge (6 seeds; docs/synthesis.md, "Density edges")."""
        xy = lo + rng.random(lo.shape) * extent

        def pixel(at: np.ndarray) -> np.ndarray:
            return self.density[pixels_of(at, self.density.shape, self.side_px)]

        inner = np.maximum(extent * (1 - 1e-9), 0.0)
        corners = [pixel(lo + inner * corner) for corner in ((0, 0), (1, 0), (0, 1), (1, 1))]
        top, low = np.max(corners, axis=0), np.min(corners, axis=0)
        todo = np.flatnonzero(low < top)
        for _ in range(64):  # the accepted share is at least the cell's mean density over its top (> 0: it has mass)
            if not len(todo):
                break
            rejected = rng.random(len(todo)) * top[todo] >= pixel(xy[todo])
            todo = todo[rejected]
            xy[todo] = lo[todo] + rng.random((len(todo), 2)) * extent[todo]
        return xy


def random_points(density: np.ndarray, side_px: int, domain: tuple[float, float], n: int,
                  rng: np.random.Generator) -> np.ndarray:
    """(n, 2) independent points with probability proportional to the (H, W) density (uniform within a pixel)."""
    flat = density.astype(np.float64).reshape(-1)
    pixel = rng.choice(len(flat), size=n, p=flat / flat.sum())
    row, col = np.divmod(pixel, density.shape[1])
    xy = (np.stack([col, row], axis=1) + rng.random((n, 2))) / side_px
    return np.minimum(xy, np.array(domain) * (1 - 1e-9))
