"""The synthesiser's nearest-neighbour term: each point's nearest neighbours within the target's own NN range.

The PCF objective of :mod:`synthesis.edgepcf` scores pair counts summed over windows of ~40 points beyond 2
standard deviations of the target's variability, so a few points that break the target's nearest-neighbour
distribution pay almost nothing: blue kept pairs at 0.45 r_max (its generator: none below 0.76), green 6 % of
points without a neighbour within 0.8 r_max (its generator 0.6 %). This term looks at each point alone, on the
pair lists the objective already has, with bounds from the target's own nearest-neighbour distances
(:meth:`synthesis.palette.Palette.neighbour_bounds_at_latent`: the 0.5 % and 99.5 % quantiles of the nearest
exemplar's, in r_max; a preset's exemplar is its generator), ``lo_c`` and ``hi_c`` times the local spacing
``s_c`` at the point's refresh position:

    L = (weight / n) [ sum_c sum_{k in pairs(c)} max(b_c, b_k) max(min(lo_c s_c, lo_k s_k) - d_ck, 0)^2
                                                 / min(s_c, s_k)^2
                       + sum_c max(min_k d_ck / s_c - hi_c, 0)^2 ]

A smooth barrier on every pair closer than both points' lower bounds (a hard core where the target has one: blue
0.76, Lloyd 0.70, lattice 0.93 r_max; a few hundredths of r_max for white, green, red), and a pull of a point whose
nearest neighbour is beyond its upper bound towards it (green 0.81, red 1.12, blue 1.03 r_max). A true sample of the
target has 1 % of its points outside the bounds, and pays for them a little, not a lot. The barrier's cost is the
squared depth in spacings: scaled as ``(1 - d / (lo s))^2`` instead, red's bound of 0.006 r_max pushed its stacked
pairs so hard that the shared step normalisation of the descent froze the rest (red's fine-PCF ratio 1.25 -> 2.97).
It takes the smaller of the two points' reaches: with the larger (or both, summed), a point on a light pixel of a
photo's fine texture (a spacing 2-3 x its neighbours') pushed every neighbour within its own wide reach away, against
the tone term (camera, 5,000 points, density PSNR at 2 spacings: 47.1 dB without the term, 44.8 with both reaches,
47.7 with the smaller).

**Stacking.** For a regular target the barrier reaches at least ``STACKING_FLOOR R`` and is stronger where its bound
is low: ``lo_c`` is ``max(lo, STACKING_FLOOR R)`` and its strength ``b_c`` is :data:`BARRIER` x
``max(1, R (STACKING_REACH / lo_c)^2)``, with ``R`` the regularity of the point's target
(:func:`synthesis.edgepcf.regularity`: 1 - its mean PCF within 0.55 r_max, clipped to [0, 1]); each colour's values
(:func:`colour_bounds`) are sampled bilinearly like the bounds. A stacked pair (d = 0) costs ``b lo^2`` (spacings^2),
so, for a target whose bound is low, almost nothing. Step noise has a soft core (its PCF about 0.3 below 0.35 r_max,
R = 0.67): 0.24 % of its generator's points have a neighbour within 0.05 r_max (the bench's stacked points; not a
numerical artefact, its NN distances are spread as ``r^2`` from 0.01 r_max up), its bound is 0.066 r_max, and with
``b = 1`` the synthesiser kept 0.15 % of its points stacked (constant map, 4,096 points, 4-12 points a seed over 6
seeds). Stacked points are not what a user wants from a regular target; with ``b`` = 9.3 (bound 0.067) none are left
and step's NN distances and fine PCF keep their generator's (min NN 0.039 -> 0.066 r_max, fine-PCF ratio 0.73 ->
0.74). A regular colour whose exemplar itself has a few stacked points (a chroma between blue and red, at the edges of
the logo's P: bound 0.009 r_max, R = 0.6) takes the floor's bound, 0.06 r_max (strength 10 instead of 500): a constant
map of it kept 8-12 stacked points of 4,096 with its own bound, none with the floor. A target with a bound of
STACKING_REACH sqrt(R) or more (blue 0.76, Lloyd 0.70, lattice 0.93 r_max) or without a short-range deficit (white,
green, red, Matern: R = 0; their stacked pairs are their clusters', their generators' 3.7-4.2 %) keeps its bound and
``b = 1``, bit for bit. A pair takes the larger of its points' strengths (symmetric: gathered per point as before).
Tried (docs/synthesis.md, "Stacking"): ``BARRIER`` 10 for every target (green's and red's edge strips 1.30 / 1.32); a
floor alone, 0.2 / 0.3 r_max x R (step stacked 0.0005 / 0, fine-PCF ratio 0.96 / 1.51); a floor of 0.06-0.07 r_max
with the stronger barrier for every target (the logo's stacking 2.3 % -> 0, but green's fine-PCF ratio 1.04 -> 1.43-1.47
and red's 1.27 -> 1.50-1.51).

**Border.** A point closer to the domain's border than its upper bound is not pulled: part of the disc in which its
nearest neighbour is expected lies outside, so its NN distance is not the torus exemplar's. Pulled there too, green's
clusters lined up 0.5-1 r_max inside the border (constant map, 4,096 points, 6 seeds: largest strip 1.38 of the
expected density, 1.22 without the pull there, 1.31 without the term).

**Cost.** At each refresh the objective's pair lists (2.6 spacings) are cut to what the term needs
(:func:`short_lists`): the pairs within a point's lower bound plus a slack and, for a point whose nearest neighbour
is within the slack of its upper bound, those within the upper bound plus the slack. The slack is :data:`SLACK` times
the point's step factor (0.5 spacings for blue; 1.5 for green and red, whose points moved up to 1.7 spacings, p99,
between two refreshes: with 0.5 the pull missed points that had become isolated since, and 1.1-2.8 % of a small green
map's points kept no neighbour within 0.8 r_max).

The pair lists are symmetric where the spacing is (both points list each other), so the barrier's gradient is
gathered per point (no writes to neighbours: parallel without buffers); the pull's share on the nearest
neighbour is scattered afterwards, one thread. :meth:`NeighbourTerm.reference` is the plain numpy version the
tests compare the numba kernel with.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from synthesis.edgepcf import regularity
from synthesis.edgepcf_fast import unsigned
from synthesis.fields import MapFields, sample_table

BARRIER = 1.0  # the barrier's weight relative to the pull's
BORDER_BAND = 1.0  # points closer to the border than this x their upper bound are not pulled (see "Border")
STACKING_FLOOR = 0.1  # r_max x regularity: the least lower bound of a regular target's barrier (see "Stacking")
STACKING_REACH = 0.25  # r_max: a regular target's stacked pair costs at least what it does under this bound (Stacking)
SLACK = 0.5  # spacings x step factor: how far points may move between refreshes for the short pair lists (see "Cost")


class NeighbourTerm:
    """The nearest-neighbour term of one map (see the module docstring).

    Call :meth:`refresh` with every new set of pair lists, then the term (fast) or :meth:`reference` (numpy).
    """

    def __init__(self, fields: MapFields, weight: float):
        self.fields = fields
        self.weight = float(weight)
        self.active = self.weight > 0 and fields.neighbour_table is not None
        self.bounds = colour_bounds(fields) if self.active else None  # (K, 3) per colour (see "Stacking")
        self.clear()

    def clear(self) -> None:
        """Drop the last refresh's arrays (the synthesiser calls it before it builds new pair lists: peak memory)."""
        self.offsets = self.neighbours = self.lower = self.upper = self.spacing = self.nearest = self.pull = None
        self.strength = None

    def refresh(self, offsets: np.ndarray, neighbours: np.ndarray, anchor: np.ndarray, spacing: np.ndarray,
                freedom: np.ndarray | float = 1.0) -> None:
        """Take pair lists (``offsets`` (n + 1,), ``neighbours`` (P,), as :class:`synthesis.edgepcf.Neighbourhoods`)
        and the bounds and barrier strengths at the refresh positions ``anchor`` (n, 2) with local spacings ``spacing``
        (n,) in map units; keep the pairs within reach of the bounds (:func:`short_lists`, a slack of :data:`SLACK` x
        ``freedom`` (n,), the points' step factor, spacings)."""
        self.clear()  # the last refresh's arrays go before the new ones are built
        bounds = sample_table(self.bounds, self.fields.colour, anchor, self.fields.side_px).astype(np.float64)
        self.spacing = np.asarray(spacing, np.float64)
        self.strength = bounds[:, 2]
        self.lower = bounds[:, 0] * self.spacing  # map units
        upper = bounds[:, 1] * self.spacing
        self.offsets, self.neighbours, candidate = short_lists(anchor, offsets, neighbours, self.lower, upper,
                                                               SLACK * freedom * self.spacing)
        self.nearest, self.pull = np.empty(len(anchor), np.int32), np.empty(len(anchor))
        width, height = self.fields.domain
        border = np.minimum(np.minimum(anchor[:, 0], width - anchor[:, 0]),
                            np.minimum(anchor[:, 1], height - anchor[:, 1]))  # distance to the domain's border
        pulled = candidate & (border >= BORDER_BAND * upper)  # see "Border"
        self.upper = np.where(pulled, bounds[:, 1], np.inf)  # spacings

    def __call__(self, xy: np.ndarray, gradient: np.ndarray | None = None) -> float:
        """Loss at xy (n, 2); adds its gradient into ``gradient`` (n, 2) when given (numba kernel)."""
        n = len(xy)
        out = np.zeros((n, 2)) if gradient is None else gradient
        loss = _neighbour_pass(xy, unsigned(self.offsets), unsigned(self.neighbours), self.lower, self.upper,
                               self.spacing, self.strength * (self.weight / n), self.weight / n, out, self.nearest,
                               self.pull)
        _scatter_pulls(xy, self.nearest, self.pull, out)
        return loss

    def reference(self, xy: np.ndarray) -> tuple[float, np.ndarray]:
        """Loss and gradient (n, 2) at xy (n, 2), plain numpy (the reference of :meth:`__call__`)."""
        xy = np.asarray(xy, np.float64)
        n = len(xy)
        centres = np.repeat(np.arange(n), np.diff(self.offsets))
        others = self.neighbours.astype(np.int64)
        offset = xy[centres] - xy[others]
        distance = np.sqrt(np.sum(offset**2, axis=1))
        barrier = np.maximum(self.strength[centres], self.strength[others]) * (self.weight / n)  # per pair
        pull = self.weight / n
        loss, slope = 0.0, np.zeros(len(distance))
        scale = np.minimum(self.spacing[centres], self.spacing[others])
        depth = np.maximum(np.minimum(self.lower[centres], self.lower[others]) - distance, 0.0) / scale  # spacings
        loss += float(np.sum(barrier * depth**2))
        slope -= 4.0 * barrier * depth / scale  # dL/dd on the centre: its own and its neighbour's directed pair
        moving = distance > 0.0
        grad = np.zeros((n, 2))
        np.add.at(grad, centres[moving], (slope[moving] / distance[moving])[:, None] * offset[moving])
        first = np.full(n, -1)
        best = np.full(n, np.inf)
        order = np.lexsort((distance, centres))  # by centre, then distance: each centre's nearest first
        starts = order[np.r_[0, np.flatnonzero(np.diff(centres[order])) + 1]] if len(order) else order
        first[centres[starts]], best[centres[starts]] = others[starts], distance[starts]
        excess = np.zeros(n)
        bounded = np.isfinite(best) & np.isfinite(self.upper)  # a neighbour, and a point that is pulled
        excess[bounded] = np.maximum(best[bounded] / self.spacing[bounded] - self.upper[bounded], 0.0)
        far = np.flatnonzero((first >= 0) & (excess > 0.0))
        loss += pull * float(np.sum(excess[far] ** 2))
        force = (2.0 * pull * excess[far] / self.spacing[far] / best[far])[:, None] * (xy[far] - xy[first[far]])
        np.add.at(grad, far, force)
        np.add.at(grad, first[far], -force)
        return loss, grad


def barrier_strength(lower: np.ndarray, regularity: np.ndarray) -> np.ndarray:
    """(...) the barrier's weight relative to the pull's for targets with lower bounds ``lower`` (..., r_max) and
    regularities (...) in [0, 1] (:func:`synthesis.edgepcf.regularity`): :data:`BARRIER` x
    ``max(1, regularity (STACKING_REACH / lower)^2)`` (see "Stacking"; BARRIER for a bound of at least
    STACKING_REACH x sqrt(regularity) or a target without a short-range deficit)."""
    reach = np.asarray(regularity, np.float64) * (STACKING_REACH / np.maximum(lower, 1e-6)) ** 2
    return BARRIER * np.maximum(1.0, reach)


def colour_bounds(fields: MapFields) -> np.ndarray:
    """(K, 3) float32 for each of the map's K colours (``fields.target_table`` rows): the barrier's lower bound, the
    colour's own (``fields.neighbour_table``) or :data:`STACKING_FLOOR` x its regularity if higher, and its upper
    bound, in r_max, and the barrier's strength (:func:`barrier_strength`); :meth:`NeighbourTerm.refresh` samples them
    bilinearly (:func:`synthesis.fields.sample_grid`'s values), so a point between two colours takes a blend of their
    strengths, not the strength of a blend (see "Stacking")."""
    bounds = fields.neighbour_table
    regular = regularity(fields.target_table.astype(np.float64), fields.radii)
    lower = np.maximum(bounds[:, 0], STACKING_FLOOR * regular)
    return np.stack([lower, bounds[:, 1], barrier_strength(lower, regular)], axis=1).astype(np.float32)


def short_lists(xy: np.ndarray, offsets: np.ndarray, neighbours: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                slack: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs the term needs from lists (``offsets`` (n + 1,), ``neighbours`` (P,)) at xy (n, 2), with the bounds
    ``lower``, ``upper`` and ``slack`` (n,) in map units: a candidate for the pull (nearest neighbour at least
    ``upper - slack`` away) keeps its pairs closer than ``upper + slack`` (at least its nearest), any other point those
    closer than ``lower + slack``. Returns (n + 1,) int64 offsets, (Q,) int32 neighbours (order kept) and (n,) bool
    candidates (numba; :func:`short_lists_reference` is the plain version)."""
    keep = np.empty(len(neighbours), np.bool_)
    candidate = np.empty(len(xy), np.bool_)
    offsets, indices = unsigned(offsets), unsigned(neighbours)
    counts = _short_counts(xy, offsets, indices, lower, upper, slack, keep, candidate, numba.get_num_threads())
    short = np.zeros(len(xy) + 1, np.int64)
    np.cumsum(counts, out=short[1:])
    kept = np.empty(short[-1], neighbours.dtype)
    _kept(offsets, indices, keep, short, unsigned(kept))  # neighbours[keep], in parallel
    return short, kept, candidate


def short_lists_reference(xy: np.ndarray, offsets: np.ndarray, neighbours: np.ndarray, lower: np.ndarray,
                          upper: np.ndarray, slack: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plain numpy version of :func:`short_lists`."""
    n = len(xy)
    centres = np.repeat(np.arange(n), np.diff(offsets))
    distance = np.sqrt(np.sum((xy[neighbours] - xy[centres]) ** 2, axis=1))
    nearest = np.full(n, np.inf)
    np.minimum.at(nearest, centres, distance)
    candidate = nearest >= upper - slack
    keep = distance < np.where(candidate, upper, lower)[centres] + slack[centres]
    at_nearest = np.flatnonzero(distance == nearest[centres])
    which = at_nearest[np.unique(centres[at_nearest], return_index=True)[1]]  # each centre's first nearest pair
    keep[which[candidate[centres[which]]]] = True
    counts = np.bincount(centres[keep], minlength=n)
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), neighbours[keep], candidate


@numba.njit(parallel=True, cache=True)
def _short_counts(xy, offsets, neighbours, lower, upper, slack, keep, candidate, threads):  # pragma: no cover - jitted
    """Mark the pairs :func:`short_lists` keeps in ``keep`` (P,) and the candidates (n,); returns kept counts (n,).
    ``offsets`` and ``neighbours`` as :func:`synthesis.edgepcf_fast.unsigned` views. Each of ``threads`` runs of
    centres keeps a centre's squared distances from the pass that finds its nearest neighbour for the pass that keeps
    its pairs (the same values, gathered once)."""
    n = len(xy)
    counts = np.zeros(n, np.int64)
    for t in numba.prange(threads):
        most = 0
        for c in range(t * n // threads, (t + 1) * n // threads):
            most = max(most, np.int64(offsets[c + 1] - offsets[c]))
        squared = np.empty(most)
        for c in range(t * n // threads, (t + 1) * n // threads):
            first = offsets[c]
            count = offsets[c + 1] - first
            for q in range(count):
                k = neighbours[first + q]
                dx, dy = xy[k, 0] - xy[c, 0], xy[k, 1] - xy[c, 1]
                squared[q] = dx * dx + dy * dy
            best, which = math.inf, count  # no pair yet (q never reaches it)
            for q in range(count):
                if squared[q] < best:
                    best, which = squared[q], q
            candidate[c] = math.sqrt(best) >= upper[c] - slack[c]
            reach = (upper[c] if candidate[c] else lower[c]) + slack[c]
            kept = 0
            for q in range(count):
                keep[first + q] = math.sqrt(squared[q]) < reach or (candidate[c] and q == which)
                kept += keep[first + q]
            counts[c] = kept
    return counts


@numba.njit(parallel=True, cache=True)
def _kept(offsets, neighbours, keep, short, out):  # pragma: no cover - jitted
    """out (Q,) = neighbours[keep], centre by centre from their short lists' ``short`` offsets (n + 1,) on
    (``offsets``, ``neighbours`` and ``out`` as :func:`synthesis.edgepcf_fast.unsigned` views)."""
    for c in numba.prange(len(offsets) - 1):
        o = short[c]
        for p in range(offsets[c], offsets[c + 1]):
            if keep[p]:
                out[o] = neighbours[p]
                o += 1


@numba.njit(parallel=True, cache=True)
def _neighbour_pass(xy, offsets, neighbours, lower, upper, spacing, barrier, pull, grad, nearest,
                    coefficient):  # pragma: no cover - jitted
    """Barrier forces gathered per point and each point's own pull; ``nearest`` (n,) int32 / ``coefficient`` (n,):
    the pulled neighbour (-1: none) and ``dL/dd / d`` of the pull, for :func:`_scatter_pulls`. Returns the loss.
    ``offsets`` and ``neighbours`` as :func:`synthesis.edgepcf_fast.unsigned` views (100k points: 3.0 -> 2.6 ms a call)."""
    n = len(xy)
    total = 0.0
    for c in numba.prange(n):
        xc, yc, reach_c = xy[c, 0], xy[c, 1], lower[c]
        best, which = math.inf, -1
        gx, gy, own = 0.0, 0.0, 0.0
        for p in range(offsets[c], offsets[c + 1]):
            k = neighbours[p]
            dx, dy = xc - xy[k, 0], yc - xy[k, 1]
            squared = dx * dx + dy * dy
            if squared < best:
                best, which = squared, k
            reach = min(reach_c, lower[k])
            if squared < reach * reach:
                d = math.sqrt(squared)
                scale = min(spacing[c], spacing[k])
                depth = (reach - d) / scale
                weight = max(barrier[c], barrier[k])
                own += weight * depth * depth
                if d > 0.0:
                    slope = -4.0 * weight * depth / scale / d  # both directed pairs' share on c
                    gx += slope * dx
                    gy += slope * dy
        nearest[c] = -1
        if which >= 0:
            d = math.sqrt(best)
            excess = d / spacing[c] - upper[c]
            if excess > 0.0:
                own_pull = pull * excess * excess
                coefficient[c] = 2.0 * pull * excess / spacing[c] / d
                nearest[c] = which
                gx += coefficient[c] * (xc - xy[which, 0])
                gy += coefficient[c] * (yc - xy[which, 1])
                total += own_pull
        grad[c, 0] += gx
        grad[c, 1] += gy
        total += own
    return total


@numba.njit(cache=True)
def _scatter_pulls(xy, nearest, coefficient, grad):  # pragma: no cover - jitted
    """The pulls' share on the pulled neighbours (one thread: two points may pull the same one)."""
    for c in range(len(xy)):
        k = nearest[c]
        if k >= 0:
            grad[k, 0] -= coefficient[c] * (xy[c, 0] - xy[k, 0])
            grad[k, 1] -= coefficient[c] * (xy[c, 1] - xy[k, 1])
