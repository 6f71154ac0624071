"""Pair correlation functions (PCFs) in units of the local point spacing.

A PCF here is sampled at ``m`` radii ``rho_j = j * BIN_WIDTH`` (default 26 radii
from 0 to 2.5) measured in units of ``r_max = 2 sqrt(A / (2 sqrt(3) n))``, the
largest possible nearest-neighbour distance of n points in area A (hexagonal
packing). Expressing distances in these units makes the same pattern at
different densities have the same PCF (paper §5, after Zhou et al. 2012).

The estimator is a ratio of observed to expected neighbours. Around a point,
a neighbour at normalised distance u is counted into the two radii around it
with linear ("tent") weights ``max(0, 1 - |u - rho_j| / BIN_WIDTH)``, and the
count is divided by what a uniform (Poisson) pattern of the same intensity
gives, so a Poisson pattern has PCF 1 at every radius. The radii start at 0
and the tent is narrow (a tenth of r_max), so stacked and too-close pairs are
seen: blue noise reads ~0 below 0.7 r_max, and a stacked pair costs. Pairs
beyond ``rho_{m-1} + BIN_WIDTH`` (:func:`neighbour_cutoff`) are never needed.

The same tent binning is the synthesis objective's estimator
(:mod:`synthesis.edgepcf`), so the palette's PCF table is in its terms.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from synthesis.errors import PatternshopError

PCF_BINS = 52
BIN_WIDTH = 0.05  # in units of r_max: radii 0, 0.05, ..., 2.55
CENTRE_CHUNK = 16384  # centres per block in stationary_pcf: bounds memory at (chunk, k) temporaries
FIRST_NEIGHBOURS = 48  # k of the first k-NN query; rows still full within the cutoff are asked again with 2k


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


def tent_counts(u: np.ndarray, weight: np.ndarray | None, radii: np.ndarray) -> np.ndarray:
    """Tent-kernel counts (m,) of normalised distances u (any shape), each with ``weight`` (same shape; None = 1).

    Distances at or beyond :func:`neighbour_cutoff` (and inf) count nothing.
    """
    width, m = _width(radii), len(radii)
    t = np.asarray(u, np.float64).reshape(-1) / width
    w = np.ones_like(t) if weight is None else np.asarray(weight, np.float64).reshape(-1)
    keep = t < m
    t, w = t[keep], w[keep]
    lower = np.floor(t).astype(np.int64)
    frac = t - lower
    counts = np.bincount(lower, w * (1 - frac), minlength=m + 1)
    counts += np.bincount(lower + 1, w * frac, minlength=m + 1)
    return counts[:m]


def uniform_expectation(radii: np.ndarray) -> np.ndarray:
    """(m,) tent counts a unit-intensity Poisson pattern gives around a point, per r_max^2, unbounded domain.

    ``int max(0, 1 - |u - rho_j| / w) 2 pi u du``: ``2 pi rho_j w^2`` for j >= 1
    (the tent is symmetric and the integrand linear in u), ``pi w^3 / 3`` at rho = 0.
    """
    width = _width(radii)
    expectation = 2.0 * math.pi * radii * width
    expectation[0] = math.pi * width**2 / 3.0
    return expectation


def neighbours_within(tree: cKDTree, centres: np.ndarray, reach: np.ndarray | float,
                      k: int = FIRST_NEIGHBOURS) -> tuple[np.ndarray, np.ndarray]:
    """Every tree point within ``reach`` (scalar or (C,)) of each centre (C, 2), the centre itself included.

    Returns distances and indices (C, K), padded with inf and ``tree.n``; K grows
    (doubling k) until no row is cut short, so clustered patterns lose no pairs.
    """
    reach = np.broadcast_to(np.asarray(reach, np.float64), (len(centres),))
    k = min(k, tree.n)
    distance, index = tree.query(centres, k=k, distance_upper_bound=float(reach.max()))
    distance, index = distance.reshape(len(centres), k), index.reshape(len(centres), k)
    while k < tree.n:
        short = distance[:, -1] <= reach  # the k-th neighbour is still within reach: there may be more
        if not short.any():
            break
        k = min(2 * k, tree.n)
        more_d, more_i = tree.query(centres[short], k=k, distance_upper_bound=float(reach[short].max()))
        distance = np.pad(distance, ((0, 0), (0, k - distance.shape[1])), constant_values=np.inf)
        index = np.pad(index, ((0, 0), (0, k - index.shape[1])), constant_values=tree.n)
        distance[short], index[short] = more_d.reshape(-1, k), more_i.reshape(-1, k)
    outside = distance > reach[:, None]
    distance[outside], index[outside] = np.inf, tree.n
    return distance, index


def stationary_pcf(
    points: np.ndarray,
    domain: tuple[float, float] = (1.0, 1.0),
    periodic: bool = True,
    radii: np.ndarray | None = None,
) -> np.ndarray:
    """PCF (m,) of a stationary pattern: points (n, 2) in ``[0, w] x [0, h]``.

    ``periodic=True`` treats the domain as a torus (palette exemplars). Otherwise
    the border is handled by minus sampling: only points at least the neighbour
    cutoff away from every border serve as centres (their neighbourhoods are
    complete), while all points count as neighbours. Memory is bounded: centres
    are processed in blocks of :data:`CENTRE_CHUNK`.
    """
    radii = pcf_radii() if radii is None else radii
    n, w, h = len(points), *domain
    spacing = r_max(n, w * h)
    reach = neighbour_cutoff(radii) * spacing
    tree, centres = _stationary_centres(points, domain, periodic, reach)
    counts = np.zeros(len(radii))
    for start in range(0, len(centres), CENTRE_CHUNK):
        distance, _ = neighbours_within(tree, centres[start:start + CENTRE_CHUNK], reach)
        counts += tent_counts(distance[:, 1:] / spacing, None, radii)  # column 0: the centre itself
    intensity = (n - 1) / (w * h)
    return counts / (len(centres) * intensity * spacing**2 * uniform_expectation(radii))


def _stationary_centres(points: np.ndarray, domain: tuple[float, float], periodic: bool,
                        reach: float) -> tuple[cKDTree, np.ndarray]:
    """Tree over points (n, 2) and the centres (C, 2) whose neighbourhood within ``reach`` is complete.

    Periodic: all points of the wrapped pattern on the torus. Otherwise minus
    sampling: the points at least ``reach`` from every border.
    """
    points = np.asarray(points, np.float64)
    w, h = domain
    if periodic:
        wrapped = np.mod(points, [w, h])
        wrapped[wrapped >= [w, h]] = 0.0
        return cKDTree(wrapped, boxsize=[w, h]), wrapped
    centres = points[np.all((points >= reach) & (points <= np.array([w, h]) - reach), axis=1)]
    if len(centres) < 10:
        raise PatternshopError(f"only {len(centres)} of {len(points)} points lie far enough from the border to estimate a PCF")
    return cKDTree(points), centres


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
    tree, centres = _stationary_centres(points, domain, periodic, reach)
    counts = []
    width, m = float(radii[1] - radii[0]), len(radii)
    for start in range(0, len(centres), CENTRE_CHUNK):
        distance, _ = neighbours_within(tree, centres[start:start + CENTRE_CHUNK], reach)
        t = distance[:, 1:] / (spacing * width)
        lower = np.floor(np.where(np.isfinite(t), t, m)).astype(np.int64)
        frac = np.where(np.isfinite(t), t - lower, 0.0)
        per_bin = np.zeros((len(t), m + 2))
        rows = np.broadcast_to(np.arange(len(t))[:, None], t.shape)
        np.add.at(per_bin, (rows, np.minimum(lower, m + 1)), np.where(lower < m, 1 - frac, 0.0))
        np.add.at(per_bin, (rows, np.minimum(lower + 1, m + 1)), np.where(lower + 1 < m, frac, 0.0))
        counts.append(np.cumsum(per_bin[:, :m], axis=1))
    counts = np.concatenate(counts)
    return counts.var(axis=0) / (counts.mean(axis=0) + 1.0)


def neighbour_lists(tree: cKDTree, centres: np.ndarray, reach: np.ndarray | float,
                    k: int = FIRST_NEIGHBOURS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every tree point within ``reach`` (scalar or (C,)) of each centre (C, 2), as compact lists (the centre itself included).

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
        out_distance[~from_query] = np.linalg.norm(tree.data[found] - centres[owner], axis=1)
    return offsets, out_index, out_distance
