"""Blue noise: Poisson-disk sampling by dart throwing on the torus.

Darts are uniform random points; a dart is kept when it lies at least ``radius``
from every kept point, until exactly n are kept. The radius is
``0.76 r_max`` (``r_max = 2 sqrt(1/(2 sqrt(3) n))``, about 1.07 mean spacings
``1/sqrt(n)``), a little below the ~0.78 at which random dart throwing jams, so
n points always fit. To keep the cost linear, darts are thrown only into the
cells of a background grid (side ``0.3 radius``) that no single disk covers
yet, the free cells being re-checked after each batch (as in Ebeida et al.
2011). Should the free area run out before n points (a maximal set smaller than
n; rare, mostly at tiny n), the radius shrinks by 2 % and throwing goes on.

The spectrum has almost no power at low frequencies (``P_b`` about 0.07 for
``b`` below a third of the peak), a peak of about 1.8 near ``b = 1.1 sqrt(n)``,
and is about 1 above; the minimum distance is at least ``0.76 r_max``.

References: M. McCool, E. Fiume, "Hierarchical Poisson disk sampling
distributions", Graphics Interface 1992; M. S. Ebeida et al., "Efficient
maximal Poisson-disk sampling", ACM TOG 30(4), 2011; A. Lagae, P. Dutré,
"A comparison of methods for generating Poisson disk distributions",
CGF 27(1), 2008 (``r_max``).
"""

from __future__ import annotations

import math

import numpy as np

from ._torus import check_count, r_max, tree, wrap

RELATIVE_RADIUS = 0.76  # Poisson-disk radius / r_max
CELL_FRACTION = 0.3  # background-grid cell side / radius
BATCH_FRACTION = 0.1  # points accepted per batch, at most, as a fraction of n
SHRINK = 0.98  # radius factor once no free area is left
STALL_BATCHES = 6  # batches in a row that accept nothing before the radius shrinks


def generate(n: int, rng: np.random.Generator, relative_radius: float = RELATIVE_RADIUS) -> np.ndarray:
    """(n, 2) float64 points in [0, 1)^2, pairwise toroidal distances >= about ``relative_radius`` r_max (at most 0.76)."""
    n = check_count(n)
    radius = relative_radius * r_max(n)
    side = math.ceil(1.0 / (CELL_FRACTION * radius))
    active = np.arange(side * side)  # cells not yet covered by a single disk
    points = np.empty((0, 2))
    free, stalled = 1.0, 0  # free: fraction of the active area that took the last batch's darts
    while len(points) < n:
        need = n - len(points)
        wanted = min(need, max(16, int(BATCH_FRACTION * n)))
        darts = _darts(rng.choice(active, max(16, math.ceil(wanted / free), len(active))), side, rng)
        thrown = len(darts)
        if len(points):
            distances, _ = tree(points).query(darts, distance_upper_bound=radius)
            darts = darts[np.isinf(distances)]
        free = max(len(darts) / thrown, 0.01)
        points = np.concatenate([points, _drop_conflicts(darts, radius)[:need]])
        stalled = 0 if len(darts) else stalled + 1
        if len(points) == n:
            break
        centres = _cell_centres(active, side)
        distances, _ = tree(points).query(centres, distance_upper_bound=radius - math.sqrt(0.5) / side)
        active = active[np.isinf(distances)]
        if len(active) == 0 or stalled >= STALL_BATCHES:
            radius *= SHRINK
            active, free, stalled = np.arange(side * side), 1.0, 0
    return points


def _cell_centres(cells: np.ndarray, side: int) -> np.ndarray:
    """(m, 2) centres of grid cells numbered ``x + side * y``."""
    return (np.stack([cells % side, cells // side], axis=1) + 0.5) / side


def _darts(cells: np.ndarray, side: int, rng: np.random.Generator) -> np.ndarray:
    """(m, 2) points, one uniform in each of the given grid cells (repeats allowed)."""
    return wrap(_cell_centres(cells, side) + (rng.random((len(cells), 2)) - 0.5) / side)


def _drop_conflicts(darts: np.ndarray, radius: float) -> np.ndarray:
    """The (m, 2) darts less the later one of every pair closer than ``radius``."""
    if len(darts) < 2:
        return darts
    pairs = tree(darts).query_pairs(radius, output_type="ndarray")
    keep = np.ones(len(darts), bool)
    keep[pairs[:, 1]] = False  # pairs are (i, j) with i < j
    return darts[keep]
