"""Pair correlation functions (PCFs) in units of the local point spacing.

A PCF here is sampled at ``m`` radii ``rho_j = j * BIN_WIDTH`` (default :data:`PCF_BINS` = 52
radii from 0 to 2.55) measured in units of ``r_max = 2 sqrt(A / (2 sqrt(3) n))``, the
largest possible nearest-neighbour distance of n points in area A (hexagonal
packing). Expressing distances in these units makes the same pattern at
different densities have the same PCF (paper §5, after Zhou et al. 2012).

The estimator is a ratio of observed to expected neighbours. Around a point,
a neighbour at normalised distance u is counted into the two radii around it
with linear ("tent") weights ``max(0, 1 - |u - rho_j| / BIN_WIDTH)``, and the
count is divided by what a uniform (Poisson) pattern of the same intensity
gives, so a Poisson pattern has PCF 1 at every radius. The radii start at 0
and the tent is narrow (half-width :data:`BIN_WIDTH` = 0.05 r_max), so stacked
and too-close pairs are seen: blue noise reads ~0 below 0.7 r_max, and a
stacked pair costs. Pairs
beyond ``rho_{m-1} + BIN_WIDTH`` (:func:`neighbour_cutoff`) are never needed.

The same tent binning is the synthesis objective's estimator
(:mod:`synthesis.edgepcf`), so the palette's PCF table is in its terms.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from synthesis.errors import PatternshopError

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

    from synthesis.cells import CellGrid

PCF_BINS = 52
BIN_WIDTH = 0.05  # in units of r_max: radii 0, 0.05, ..., 2.55
CENTRE_CHUNK = 16384  # centres per block in stationary_pcf: bounds memory at (chunk, k) temporaries
FIRST_NEIGHBOURS = 48  # k of the first k-NN query; centres with more neighbours within reach get a radius query


def r_max(n: float | np.ndarray, area: float = 1.0) -> float | np.ndarray:
    """Largest nearest-neighbour distance of n points in ``area`` (hexagonal packing); works on arrays."""
    return 2.0 * np.sqrt(area / (2.0 * math.sqrt(3.0) * n))


def pcf_radii(bins: int = PCF_BINS, width: float = BIN_WIDTH) -> np.ndarray:
    """(bins,) radii ``rho_j = j * width`` in units of r_max."""
    return np.arange(bins) * width


def neighbour_cutoff(radii: np.ndarray) -> float:
    """Largest normalised distance that still counts: the last radius plus one bin width."""
    return float(radii[-1] + _width(radii))


def _width(radii: np.ndarray) -> float:
    return float(radii[1] - radii[0])


def uniform_expectation(radii: np.ndarray) -> np.ndarray:
    """(m,) tent counts a unit-intensity Poisson pattern gives around a point, per r_max^2, unbounded domain.

    ``int max(0, 1 - |u - rho_j| / w) 2 pi u du``: ``2 pi rho_j w^2`` for j >= 1
    (the tent is symmetric and the integrand linear in u), ``pi w^3 / 3`` at rho = 0.
    """
    width = _width(radii)
    expectation = 2.0 * math.pi * radii * width
    expectation[0] = math.pi * width**2 / 3.0
    return expectation


def stationary_pcf(
    points: np.ndarray,
    domain: tuple[float, float] = (1.0, 1.0),
    periodic: bool = True,
    radii: np.ndarray | None = None,
    progress: Callable[[float], None] | None = None,
) -> np.ndarray:
    """PCF (m,) of a stationary pattern: points (n, 2) in ``[0, w] x [0, h]``.

    ``periodic=True`` treats the domain as a torus (palette exemplars). Otherwise
    the border is handled by minus sampling: only points at least the neighbour
    cutoff away from every border serve as centres (their neighbourhoods are
    complete), while all points count as neighbours. Memory is bounded: centres
    are processed in blocks of :data:`CENTRE_CHUNK` (``progress(fraction of the
    centres done)`` after each; Ctrl+C is honoured between them).
    """
    radii = pcf_radii() if radii is None else radii
    n, w, h = len(points), *domain
    spacing = r_max(n, w * h)
    reach = neighbour_cutoff(radii) * spacing
    grid, centres = _stationary_centres(points, domain, periodic, reach)
    counts, done = np.zeros(len(radii)), 0
    for block in _centre_counts(grid, centres, reach, spacing, radii):
        counts += block.sum(axis=0)
        done += len(block)
        if progress is not None:
            progress(done / len(centres))
    intensity = (n - 1) / (w * h)
    return counts / (len(centres) * intensity * spacing**2 * uniform_expectation(radii))


def _stationary_centres(points: np.ndarray, domain: tuple[float, float], periodic: bool,
                        reach: float) -> tuple[CellGrid, np.ndarray]:
    """Cell grid over points (n, 2) and the centres (C, 2) whose neighbourhood within ``reach`` is complete.

    Periodic: all points of the wrapped pattern on the torus. Otherwise minus
    sampling: the points at least ``reach`` from every border.
    """
    from synthesis.cells import CellGrid  # here: numba's import (0.1 s) stays out of infer, which needs only r_max

    points = np.asarray(points, np.float64)
    w, h = domain
    if periodic:
        wrapped = np.mod(points, [w, h])
        wrapped[wrapped >= [w, h]] = 0.0
        return CellGrid(wrapped, domain, reach, periodic=True), wrapped
    centres = points[np.all((points >= reach) & (points <= np.array([w, h]) - reach), axis=1)]
    if len(centres) < 10:
        raise PatternshopError(f"only {len(centres)} of {len(points)} points lie far enough from the border to estimate a PCF")
    return CellGrid(points, domain, reach), centres


def _centre_counts(grid: CellGrid, centres: np.ndarray, reach: float, spacing: float, radii: np.ndarray):  # noqa: ANN202
    """Tent counts (c, m) around each centre, itself excluded, in blocks of :data:`CENTRE_CHUNK` centres (a generator).

    Distances are in units of ``spacing``; neighbours at or beyond
    :func:`neighbour_cutoff` count nothing.
    """
    width, m = _width(radii), len(radii)
    for start in range(0, len(centres), CENTRE_CHUNK):
        block = centres[start:start + CENTRE_CHUNK]
        offsets, _, distance = grid.query(block, reach)
        owner = np.repeat(np.arange(len(block)), np.diff(offsets))
        t = distance / (spacing * width)
        keep = t < m
        owner, t = owner[keep], t[keep]
        lower = np.floor(t).astype(np.int64)
        frac = t - lower
        cells = len(block) * (m + 1)
        flat = np.bincount(owner * (m + 1) + lower, 1 - frac, minlength=cells)
        flat += np.bincount(owner * (m + 1) + lower + 1, frac, minlength=cells)
        counts = flat.reshape(len(block), m + 1)[:, :m]
        counts[:, 0] -= 1.0  # every centre found itself at distance 0
        yield counts


def count_dispersion(points: np.ndarray, domain: tuple[float, float] = (1.0, 1.0), periodic: bool = True,
                     radii: np.ndarray | None = None) -> np.ndarray:
    """(m,) dispersion of a stationary pattern's per-point cumulative counts: variance / (mean + 1), per radius.

    The count around a point of neighbours closer than each radius (tent
    binned, cumulated) varies from point to point; this is its variance
    relative to a Poisson pattern's (whose variance equals the mean; the +1
    keeps hard-core radii, where both are 0, finite). About 1 for Poisson,
    below 1 for regular patterns, above for clustered ones. Points (n, 2) in
    ``[0, w] x [0, h]``; borders as in :func:`stationary_pcf`.
    """
    radii = pcf_radii() if radii is None else radii
    n, w, h = len(points), *domain
    spacing = r_max(n, w * h)
    reach = neighbour_cutoff(radii) * spacing
    grid, centres = _stationary_centres(points, domain, periodic, reach)
    counts = np.cumsum(np.concatenate(list(_centre_counts(grid, centres, reach, spacing, radii))), axis=1)
    return counts.var(axis=0) / (counts.mean(axis=0) + 1.0)


def neighbour_lists(tree: cKDTree, centres: np.ndarray, reach: np.ndarray | float,
                    k: int = FIRST_NEIGHBOURS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every tree point within ``reach`` (scalar or (C,)) of each centre (C, 2), as compact lists (the centre itself included).

    The plain reference of :meth:`synthesis.cells.CellGrid.query` (tests compare them).

    Returns offsets (C + 1,) int64 (the entries of centre c are ``offsets[c]:offsets[c + 1]``),
    indices (E,) int64 and distances (E,). One k-NN query serves most centres;
    those whose k-th neighbour is still within reach (dense clusters, or a
    light area whose reach covers a dark one) get a radius query of their own,
    so memory follows the actual pair count.
    """
    centres = np.asarray(centres, np.float64)
    reach = np.broadcast_to(np.asarray(reach, np.float64), (len(centres),))
    k = min(k, tree.n)
    distance, index = tree.query(centres, k=k)
    distance, index = distance.reshape(len(centres), k), index.reshape(len(centres), k)
    keep = distance <= reach[:, None]
    short = keep[:, -1] & (k < tree.n)  # may have more neighbours than k
    keep[short] = False
    counts = keep.sum(axis=1)
    extra: list[np.ndarray] = []
    if short.any():
        extra = [np.asarray(found, np.int64) for found in tree.query_ball_point(centres[short], reach[short])]
        counts[short] = [len(found) for found in extra]
    offsets = np.zeros(len(centres) + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    out_index = np.empty(offsets[-1], np.int64)
    out_distance = np.empty(offsets[-1])
    from_query = np.repeat(~short, counts)
    out_index[from_query], out_distance[from_query] = index[keep], distance[keep]
    if extra:
        found = np.concatenate(extra)
        owner = np.repeat(np.flatnonzero(short), counts[short])
        out_index[~from_query] = found
        offset = tree.data[found] - centres[owner]
        if tree.boxsize is not None:  # periodic tree: minimum-image distances
            box = np.asarray(tree.boxsize)[: offset.shape[1]]
            offset -= box * np.round(offset / box)
        out_distance[~from_query] = np.linalg.norm(offset, axis=1)
    return offsets, out_index, out_distance
