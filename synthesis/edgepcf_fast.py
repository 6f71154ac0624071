"""Fused numba kernels for the synthesis objective of :mod:`synthesis.edgepcf` (same maths, same results).

One evaluation is three parallel passes over spatially sorted points:

1. by centre: tent-count the pairs (per radius, not cumulated), minus the
   expected counts' change along their slope near borders and edges, into the
   windows of the point; each pair's bin and tent slope are kept for pass 3;
2. by window (both window families in one list): those sums plus the
   expected counts at the anchors (fixed between refreshes, so summed once
   per refresh), cumulated over the radii, standardised, scored with the dead
   zone; the loss and each window's slope (and whether it has any);
3. by centre: gather the slopes of the windows the point belongs to
   (transposed membership lists; windows inside their dead zone skipped),
   and turn them into forces on the point's pairs (a pair in bin j feels
   minus the gathered slope at j: no integration back over the radii);
   forces on neighbours go to a per-thread buffer (threads own contiguous
   runs of centres), so no two threads write one element and no per-pair
   force is stored.

Cumulating per window instead of per point is the same sum in another order
(float32 rounding only; it agrees with the reference ~10 x closer than the
per-point cumulation did). Buffers are allocated once per neighbourhood
refresh, never per iteration.
:class:`FastObjective` must agree with :func:`synthesis.edgepcf.objective_reference`
(tests compare them).
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import numba
import numpy as np

from synthesis.fields_fast import corners, guide_gap
from synthesis.workspace import Workspace, scratch

if TYPE_CHECKING:
    from synthesis.edgepcf import Neighbourhoods
    from synthesis.fields import Denominators, MapFields

_JIT = {"parallel": True, "cache": True, "fastmath": False}
# the two per-iteration kernels may reorder and fuse float32 arithmetic (SIMD): results agree with the reference to ~1e-6
_HOT = {"parallel": True, "cache": True, "fastmath": {"contract", "reassoc", "arcp"}}
# the workspace buffer of the window sums (see :func:`_window_buffers`; float64), also the window queries' distances
WINDOW_PARTS = "window_parts"


@numba.njit(**_JIT)
def _expected_window_sums(target, colour, side_px, anchor, exact, slot, denominators, member_offsets, member_window,
                          member_weight, parts):  # pragma: no cover - jitted
    """Per-thread window sums (threads, W, m) float64 of ``-a g D`` (per radius, not cumulated): fixed for a refresh.
    ``target`` (C, m): the target's rows, indexed per pixel by ``colour`` (H, W) (:class:`synthesis.fields.MapFields`);
    the point lists as :func:`unsigned` views."""
    threads, _, m = parts.shape
    n = len(anchor)
    height, width = colour.shape
    for t in numba.prange(threads):
        acc = parts[t]
        acc[:] = 0.0
        row = np.empty(m, np.float32)
        for c in range(t * n // threads, (t + 1) * n // threads):
            r0, r1, c0, c1, tx, ty = corners(height, width, anchor[c, 0] * side_px - 0.5, anchor[c, 1] * side_px - 0.5)
            w00, w01 = np.float32((1.0 - tx) * (1.0 - ty)), np.float32(tx * (1.0 - ty))
            w10, w11 = np.float32((1.0 - tx) * ty), np.float32(tx * ty)
            k00, k01, k10, k11 = colour[r0, c0], colour[r0, c1], colour[r1, c0], colour[r1, c1]
            k = slot[c]
            denominator = exact if k < 0 else denominators[k]
            for j in range(m):
                g = w00 * target[k00, j] + w01 * target[k01, j] + w10 * target[k10, j] + w11 * target[k11, j]
                row[j] = -g * denominator[j]
            for e in range(member_offsets[c], member_offsets[c + 1]):
                a = member_weight[e]
                w = member_window[e]
                for j in range(m):
                    acc[w, j] += a * row[j]


@functools.lru_cache(maxsize=None)
def _kernels_for(m: int) -> tuple:
    """The kernels that loop over the radii at every point, compiled for ``m`` radii: the two per iteration (window
    sums of counts, gradient) and the refresh's point terms. With ``m`` a compile-time constant their loops over the
    radii unroll and vectorise (100k points, one thread, the same loops over a run-time ``m`` before: 28 -> 23 ms,
    16 -> 13 ms and 38 -> 28 ms per call). Cached on disk per ``m``, as every kernel. Their index arrays (offsets,
    neighbours, window lists, pair bins) come as :func:`unsigned` views."""

    @numba.njit(**_HOT)
    def window_sums_of_counts(xy, offsets, neighbours, guide, spacing, inv_width, anchor, slot, slope_x, slope_y,
                              member_offsets, member_window, member_weight, sums, pair_bin, pair_pull,
                              guided):  # pragma: no cover - jitted
        threads = sums.shape[0]
        n = len(xy)
        for t in numba.prange(threads):
            acc = sums[t]
            acc[:] = 0.0
            row = np.empty(m + 1, np.float32)  # row[m]: the upper tent share of a pair in the last bin, dropped
            most = 0
            for c in range(t * n // threads, (t + 1) * n // threads):
                most = max(most, np.int64(offsets[c + 1] - offsets[c]))
            pair_distance = np.empty(most)  # a centre's pair distances: its square roots and divisions in a loop of
            # their own, apart from the scattered tent counts (the same values; 100k points: 6 % less time a call)
            offset_x, offset_y = np.empty(most), np.empty(most)  # the offsets gathered first: the square roots and
            # divisions then run on contiguous arrays (SIMD; the same values, 100k points: 5 % less time a call)
            for c in range(t * n // threads, (t + 1) * n // threads):
                k = slot[c]
                if k >= 0:  # the expected counts g D at the anchor (in the refresh's fixed sums) moved along their slope
                    mx, my = xy[c, 0] - anchor[c, 0], xy[c, 1] - anchor[c, 1]
                    for j in range(m):
                        row[j] = -(slope_x[k, j] * mx + slope_y[k, j] * my)
                else:
                    for j in range(m):
                        row[j] = 0.0
                row[m] = 0.0
                scale = inv_width / spacing[c]
                xc, yc = xy[c, 0], xy[c, 1]
                first = offsets[c]
                count = offsets[c + 1] - first
                for q in range(count):
                    b = neighbours[first + q]
                    offset_x[q], offset_y[q] = xy[b, 0] - xc, xy[b, 1] - yc
                for q in range(count):
                    pair_distance[q] = math.sqrt(offset_x[q] * offset_x[q] + offset_y[q] * offset_y[q])
                for q in range(count):  # for the gradient: the tent's slope along the offset (guide 1: not read, the
                    # same values; 100k points, one colour: 2-3 % less time a call)
                    if pair_distance[q] > 0.0:
                        pair_pull[first + q] = (guide[first + q] if guided else 1.0) * scale / pair_distance[q]
                for q in range(count):  # plus the tent counts of the pairs
                    p = first + q
                    distance = pair_distance[q]
                    d = distance * scale
                    pair_bin[p] = -1  # none (the largest value of the unsigned view)
                    if d < m:
                        j = numba.uint64(d)  # int(d), unsigned: no wraparound on row[j]
                        f = d - j
                        g = guide[p] if guided else np.float32(1.0)
                        row[j] += g * (1.0 - f)
                        row[j + numba.uint64(1)] += g * f
                        if distance > 0.0:  # for the gradient: the pair's bin (its pull is read only there)
                            pair_bin[p] = j
                for e in range(member_offsets[c], member_offsets[c + 1]):  # into the windows of the point (cumulated there)
                    a = member_weight[e]
                    w = member_window[e]
                    for j in range(m):
                        acc[w, j] += a * row[j]

    @numba.njit(**_HOT)
    def gradient(xy, offsets, neighbours, point_offsets, point_window, point_weight, slope, active, slot, cumulative_x,
                 cumulative_y, variance_force, pair_bin, pair_pull, parts):  # pragma: no cover - jitted
        threads, n, _ = parts.shape
        for t in numba.prange(threads):
            part = parts[t]
            part[:] = 0.0
            raw = np.empty(m, np.float32)
            for c in range(t * n // threads, (t + 1) * n // threads):
                # raw[j]: dL/dS at radius j summed over the point's windows; dL/d(count in bin j) is its sum over radii
                # >= j, so a pair's tent derivative (that sum at j + 1 minus at j) is -raw[j] and the slope terms pair
                # raw with the slopes cumulated over the radii (no per-point integration); the index arrays come as
                # :func:`unsigned` views (pair_bin's "none" is then its largest value)
                for j in range(m):
                    raw[j] = 0.0
                for e in range(point_offsets[c], point_offsets[c + 1]):
                    w = point_window[e]
                    if active[w]:
                        a = point_weight[e]
                        for j in range(m):
                            raw[j] += a * slope[w, j]
                gx, gy = 0.0, 0.0
                k = slot[c]
                if k >= 0:
                    for j in range(m):
                        gx -= raw[j] * cumulative_x[k, j]
                        gy -= raw[j] * cumulative_y[k, j]
                    gx += variance_force[k, 0]
                    gy += variance_force[k, 1]
                xc, yc = xy[c, 0], xy[c, 1]
                for p in range(offsets[c], offsets[c + 1]):  # the pairs' bins and slopes from window_sums_of_counts
                    j = pair_bin[p]
                    if j < m:
                        b = neighbours[p]
                        pull = -raw[j] * pair_pull[p]
                        fx, fy = pull * (xy[b, 0] - xc), pull * (xy[b, 1] - yc)
                        part[b, 0] += fx
                        part[b, 1] += fy
                        gx -= fx
                        gy -= fy
                part[c, 0] += gx
                part[c, 1] += gy

    @numba.njit(**_JIT)
    def point_terms(target, dispersion, colour, px, py, exact, slot, values, short, tolerance, structure_range,
                    member_offsets, member_window, member_weight, squares, regularity,
                    structure):  # pragma: no cover - jitted
        threads = squares.shape[0]
        n = len(px)
        height, width = colour.shape
        for t in numba.prange(threads):
            acc = squares[t]
            acc[:] = 0.0
            g, s, variance = np.empty(m, np.float32), np.empty(m, np.float32), np.empty(m)
            for c in range(t * n // threads, (t + 1) * n // threads):
                r0, r1, c0, c1, tx, ty = corners(height, width, px[c], py[c])
                k00, k01, k10, k11 = colour[r0, c0], colour[r0, c1], colour[r1, c0], colour[r1, c1]
                for j in range(m):  # bilinear, rounded to float32 as synthesis.fields.sample_grid gives it
                    g[j] = np.float32((target[k00, j] * (1.0 - tx) + target[k01, j] * tx) * (1.0 - ty)
                                      + (target[k10, j] * (1.0 - tx) + target[k11, j] * tx) * ty)
                for j in range(m):
                    s[j] = np.float32((dispersion[k00, j] * (1.0 - tx) + dispersion[k01, j] * tx) * (1.0 - ty)
                                      + (dispersion[k10, j] * (1.0 - tx) + dispersion[k11, j] * tx) * ty)
                total, below, furthest = 0.0, 0.0, 0.0
                k = slot[c]
                for j in range(m):
                    total += g[j] * (exact[j] if k < 0 else values[k, j])
                    variance[j] = s[j] * (total + 1.0)
                for j in range(short):
                    below += g[j]
                for j in range(m):
                    furthest = max(furthest, abs(g[j] - 1.0))
                regularity[c] = min(max(1.0 - below / short, 0.0), 1.0)
                structure[c] = min(max((furthest - tolerance) / structure_range, 0.0), 1.0)
                for e in range(member_offsets[c], member_offsets[c + 1]):
                    a = member_weight[e]
                    w = member_window[e]
                    for j in range(m):
                        acc[w, j] += a * a * variance[j]

    return window_sums_of_counts, gradient, point_terms


@numba.njit(**_JIT)
def _window_slopes(sums, expected, deviation, dead, scale, slope, loss, active):  # pragma: no cover - jitted
    threads, windows, m = sums.shape
    for w in numba.prange(windows):
        penalty = 0.0
        total = 0.0  # the window's cumulative count minus its expectation, over the radii
        outside = False  # beyond its dead zone at some radius; a window inside it at every radius has no slope, and
        # the gradient skips it
        for j in range(m):
            total -= expected[w, j]
            for t in range(threads):
                total += sums[t, w, j]
            x = total / deviation[w, j]
            excess = abs(x) - dead[w]
            if excess > 0.0:
                penalty += excess * excess
                outside = True
                slope[w, j] = math.copysign(2.0 * excess, x) * scale[w] / deviation[w, j]
            else:
                slope[w, j] = 0.0
        loss[w] = penalty * scale[w]
        active[w] = outside


@numba.njit(**_JIT)
def _row_guides(latent, row_latent, offsets, members, bandwidth, out):  # pragma: no cover - jitted
    for r in numba.prange(len(offsets) - 1):
        for p in range(offsets[r], offsets[r + 1]):
            d2 = 0.0
            for c in range(latent.shape[1]):
                d = guide_gap(latent[members[p], c] - row_latent[r, c], c)
                d2 += d * d
            out[p] = math.exp(-d2 / (2.0 * bandwidth)) if d2 > 1e-20 else 1.0  # exp rounds to 1.0 there anyway


def row_guides(latent: np.ndarray, row_latent: np.ndarray, offsets: np.ndarray, members: np.ndarray,
               bandwidth: float, out: np.ndarray | None = None) -> np.ndarray:
    """(E,) guidance H between each entry's point and its row: ``exp(-|latent[members[p]] - row_latent[r]|^2 / (2 bandwidth))``.

    latent (n, C) guide coordinates at the points (:meth:`synthesis.fields.MapFields.guide_at`; the third, the density
    level, through :func:`synthesis.fields_fast.guide_gap`), row_latent (R, C) at the rows (centres or windows), CSR
    offsets (R + 1,) over members (E,); ``out``: an (E,) float64 array to fill. Same values as :func:`synthesis.fields.guide_similarity`.
    """
    out = np.empty(len(members)) if out is None else out
    _row_guides(np.ascontiguousarray(latent, np.float64), np.ascontiguousarray(row_latent, np.float64), offsets, members,
                float(bandwidth), out)
    return out


def point_terms(fields: MapFields, xy: np.ndarray, denominators: Denominators, members: tuple[np.ndarray, np.ndarray, np.ndarray],
                windows: int, short: int, tolerance: float, structure_range: float,
                threads: int | None = None, workspace: Workspace | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-point terms at xy (n, 2), the target and dispersion sampled on the fly (bilinear, float32 as
    :func:`synthesis.fields.sample_grid`):

    the window sums (``windows``, m) of ``a_wc^2 V_c``, V_c the variance of point c's cumulative counts,
    ``dispersion (cumsum(g D) + 1)`` (the windows' Poisson-model variance; ``members``: the point lists of
    :func:`point_lists`), and the target's regularity (n,) (1 - mean of its first ``short`` radii) and structure (n,)
    (see :func:`synthesis.edgepcf.structure`). No (n, m) array is stored. The sums live in ``workspace``'s
    :data:`WINDOW_PARTS` buffer (overwritten by the next use).
    """
    n, m = len(xy), len(fields.radii)
    threads = _threads(threads)
    squares = _window_buffers(scratch(workspace), threads, windows, m)[0]
    regularity, structure = np.empty(n), np.empty(n)
    kernel = _kernels_for(m)[2]
    kernel(fields.target_table, fields.dispersion_table, fields.colour, xy[:, 0] * fields.side_px - 0.5,
           xy[:, 1] * fields.side_px - 0.5, denominators.exact, denominators.slot, denominators.values, short, tolerance,
           structure_range, unsigned(members[0]), unsigned(members[1]), members[2], squares, regularity, structure)
    return _thread_total(squares), regularity, structure


def _window_buffers(workspace: Workspace, threads: int, windows: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-thread window sums in one workspace buffer (:data:`WINDOW_PARTS`): a refresh's float64 parts (threads, W, m)
    (the point terms' squares, then the expected counts' sums, which stay in the first part as ``window_expected``)
    and the iterations' float32 sums (threads, W, m) from the second part on: over float64 parts that nothing reads
    once the refresh summed them into the first. The refresh's window queries put their distances there first.

    One buffer instead of three (the distances', the parts', the sums'; 1M points, 2 threads: 108 MB instead of 201 MB).
    """
    size = windows * m
    flat = workspace.empty(WINDOW_PARTS, max(threads * size, size + (threads * size + 1) // 2))
    return flat[:threads * size].reshape(threads, windows, m), flat[size:].view(np.float32)[:threads * size].reshape(
        threads, windows, m)


def _same_array(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether a and b are the same elements of the same memory (shape, dtype, strides and address)."""
    return (a.shape, a.dtype, a.strides, a.__array_interface__["data"][0]) == (
        b.shape, b.dtype, b.strides, b.__array_interface__["data"][0])


def unsigned(indices: np.ndarray) -> np.ndarray:
    """The same memory as unsigned integers of the same width: for index arrays whose values are never negative (or
    whose -1 means none, then the largest value). Numba indexes with a signed integer through a wraparound for
    negative values (a few instructions at every access); with unsigned ones it does not. The hot kernels take their
    offsets, neighbours, window lists and pair bins this way (the same results bit for bit; 100k points, one thread:
    window sums of counts 19.4 -> 16.0 ms, gradient 13.4 -> 11.1 ms a call)."""
    return indices.view(np.dtype(f"u{indices.dtype.itemsize}"))


def cumulate(values: np.ndarray) -> np.ndarray:
    """``np.cumsum(values, axis=1, out=values)`` on a float64 array (K, m, ...), in place and returned: the same
    additions in the same order, as m - 1 additions of whole columns (numpy's cumsum along axis 1 runs its inner loop
    once per row: K = 2,345 and m = 52, 0.43 -> 0.16 ms; (K, m, 2): 0.88 -> 0.31 ms; a refresh takes three)."""
    for rest in np.ndindex(values.shape[2:]):
        for j in range(1, values.shape[1]):
            previous, column = values[(slice(None), j - 1, *rest)], values[(slice(None), j, *rest)]
            np.add(previous, column, out=column)
    return values


def _thread_total(parts: np.ndarray) -> np.ndarray:
    """Per-thread parts (threads, ...) summed into ``parts[0]``, in place (the additions of ``parts.sum(axis=0)``, in
    its order); returns that view."""
    total = parts[0]
    for part in parts[1:]:
        total += part
    return total


def _threads(threads: int | None) -> int:
    """Thread runs of a chunked kernel: ``threads`` capped at numba's count (default: numba's count)."""
    return numba.get_num_threads() if threads is None else max(1, min(threads, numba.get_num_threads()))


@numba.njit(cache=True)
def _count_members(members, counts):  # pragma: no cover - jitted
    for q in range(len(members)):
        counts[members[q] + 1] += 1


@numba.njit(cache=True)
def _scatter_members(offsets, members, weights, first_window, fill, point_window, point_weight):  # pragma: no cover
    for w in range(len(offsets) - 1):
        for q in range(offsets[w], offsets[w + 1]):
            e = fill[members[q]]
            point_window[e] = first_window + w
            point_weight[e] = weights[q]
            fill[members[q]] += 1


@numba.njit(cache=True)
def _window_totals(offsets, weights, out):  # pragma: no cover - jitted
    for w in range(len(offsets) - 1):
        total = 0.0
        for q in range(offsets[w], offsets[w + 1]):
            total += weights[q]
        out[w] = total


def window_totals(offsets: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(W,) float64 each window's sum of its weights (E,) (CSR offsets (W + 1,)): ``np.bincount(owners, weights)``, the
    same additions in the same order, without the (E,) owners (1M points: 18 MB at a refresh)."""
    out = np.empty(len(offsets) - 1)
    _window_totals(offsets, weights, out)
    return out


def window_bounds(families: list) -> np.ndarray:
    """(F + 1,) the windows of family f are numbered ``bounds[f]:bounds[f + 1]`` in the point lists."""
    return np.cumsum([0] + [len(windows.offsets) - 1 for windows in families])


def point_lists(families: list, n: int, workspace: Workspace | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The windows each point belongs to, over all families (window indices numbered family after family).

    Returns offsets (n + 1,) int64, window (E,) int32 and weight (E,) float32 (a counting sort, no concatenation).
    """
    workspace = scratch(workspace)
    offsets = np.zeros(n + 1, np.int64)
    for windows in families:
        _count_members(windows.members, offsets)
    np.cumsum(offsets, out=offsets)
    window = workspace.empty("points.window", offsets[-1], np.int32)
    weight = workspace.empty("points.weight", offsets[-1], np.float32)
    fill, first = offsets[:-1].copy(), 0
    for windows in families:
        _scatter_members(windows.offsets, windows.members, windows.weights, first, fill, window, weight)
        first += len(windows.offsets) - 1
    return offsets, window, weight


@numba.njit(**_JIT)
def _window_weights(distance, offsets, reach, latent, members, centre_latent, bandwidth, guide, out):  # pragma: no cover
    for w in numba.prange(len(offsets) - 1):
        for q in range(offsets[w], offsets[w + 1]):
            u = distance[q] / reach[w]
            taper = max(1.0 - u * u, 0.0)
            weight = taper * taper
            if guide:
                da, db = latent[members[q], 0] - centre_latent[w, 0], latent[members[q], 1] - centre_latent[w, 1]
                d2 = da * da + db * db
                if d2 > 1e-20:
                    weight *= math.exp(-d2 / (2.0 * bandwidth))
            out[q] = weight


def window_weights(distance: np.ndarray, offsets: np.ndarray, reach: np.ndarray, latent: np.ndarray, members: np.ndarray,
                   centre_latent: np.ndarray | None, bandwidth: float, out: np.ndarray) -> np.ndarray:
    """Window weights into out (E,) float32: taper ``(1 - (d / reach)^2)^2`` times guidance H (when ``centre_latent`` is given).

    distance (E,) of each member from its window's centre, CSR offsets (W + 1,), reach (W,), latent (n, 2) at the
    points, members (E,), centre_latent (W, 2) at the windows' centres. Same values as
    :func:`synthesis.edgepcf.window_taper` x :func:`synthesis.fields.guide_similarity`.
    """
    guide = centre_latent is not None
    centres = np.ascontiguousarray(centre_latent, np.float64) if guide else np.zeros((len(reach), 2))
    _window_weights(distance, offsets, reach, np.ascontiguousarray(latent, np.float64), members, centres, float(bandwidth),
                    guide, out)
    return out


@numba.njit(**_JIT)
def _sloped_window_sums(sloped, point_offsets, point_window, point_weight, first, last, values, out):  # pragma: no cover
    for k in numba.prange(len(sloped)):
        c = sloped[k]
        for j in range(out.shape[1]):
            out[k, j] = 0.0
        for e in range(point_offsets[c], point_offsets[c + 1]):
            w = point_window[e]
            if first <= w < last:
                a = point_weight[e]
                for j in range(out.shape[1]):
                    out[k, j] += a * a * values[w - first, j]


def sloped_window_sums(sloped: np.ndarray, point_offsets: np.ndarray, point_window: np.ndarray, point_weight: np.ndarray,
                       first: int, values: np.ndarray) -> np.ndarray:
    """(K, m) ``sum a_wc^2 values[w - first]`` over the windows ``first <= w < first + W`` of each point c in ``sloped`` (K,).

    values (W, m): one family's per-window rows; the point lists come from :func:`point_lists`.
    """
    out = np.empty((len(sloped), values.shape[1]))
    _sloped_window_sums(sloped, point_offsets, point_window, point_weight, first, first + len(values),
                        np.ascontiguousarray(values, np.float64), out)
    return out


def window_sums(hood: Neighbourhoods, xy: np.ndarray, workspace: Workspace | None = None,
                threads: int | None = None, level_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Every window's sums (W, m) float64, per radius (not cumulated), over all families (numbered as in
    :func:`point_lists`): of its points' tent counts ``sum_c a_wc S_c`` at xy (n, 2) (the anchors, where nothing has
    moved along its slope), and of their expected counts ``sum_c a_wc g D_c`` at the anchors.

    ``hood`` needs its pair lists, guides, spacings, anchors, target, denominators and point lists (its slopes are not
    read). The same passes as :class:`FastObjective`'s (its buffers in ``workspace``; the expected sums are a view of
    its :data:`WINDOW_PARTS` buffer). ``level_only``: the tent counts' sums of the level windows only
    (:attr:`synthesis.edgepcf.WindowScale.level`, all that :func:`synthesis.edgepcf.slope_levels` reads), the other rows
    0 (never written: 1M points, 54 MB less at a refresh). Sets ``hood.anchor_counts`` where xy are the anchors and the
    counts outlive the expected sums (one thread): the objective's first evaluation reads them, so nothing may write
    these buffers in between (:func:`synthesis.edgepcf.find_neighbourhoods` does not;
    ``tests/test_synthesis_fast.py::test_first_objective_call_at_the_anchors_reads_the_refresh_counts``).
    """
    workspace = scratch(workspace)
    threads = _threads(threads)
    n, m = len(xy), len(hood.radii)
    windows = int(window_bounds(hood.windows)[-1])
    parts = _window_buffers(workspace, threads, windows, m)[1]  # the expected sums go over the counts' parts
    pairs = len(hood.neighbours)
    pair_bin = workspace.empty("objective.pair_bin", pairs, np.int16 if m < 2 ** 15 else np.int32)
    no_slope = np.zeros((1, m))
    pair_pull = workspace.empty("objective.pair_pull", pairs, np.float32)
    window_sums_of_counts = _kernels_for(m)[0]
    window_sums_of_counts(xy, unsigned(hood.offsets), unsigned(hood.neighbours), hood.guide, hood.spacing,
                          1.0 / float(hood.radii[1] - hood.radii[0]), xy, np.full(n, -1, np.int32), no_slope, no_slope,
                          unsigned(hood.member_offsets), unsigned(hood.member_window), hood.member_weight, parts,
                          unsigned(pair_bin), pair_pull, hood.guided)
    if level_only:
        observed = np.zeros((windows, m))
        bounds = window_bounds(hood.windows)
        for family, lo, hi in zip(hood.windows, bounds[:-1], bounds[1:]):
            if family.scale.level:
                np.sum(parts[:, lo:hi], axis=0, dtype=np.float64, out=observed[lo:hi])
    else:
        observed = parts.sum(axis=0, dtype=np.float64)
    # the counts at the anchors stay for the objective's first evaluation there, unless the expected sums' per-thread
    # parts go over them (several threads)
    kept = np.array_equal(xy, hood.anchor) and not np.shares_memory(parts, _window_buffers(workspace, threads, windows, m)[0])
    hood.anchor_counts = (parts, pair_bin, pair_pull) if kept else None
    return observed, expected_window_sums(hood, workspace, threads)


def expected_window_sums(hood: Neighbourhoods, workspace: Workspace | None = None,
                         threads: int | None = None) -> np.ndarray:
    """(W, m) float64 every window's sum of its points' expected counts ``sum_c a_wc g D_c`` at the anchors, per radius
    (the second half of :func:`window_sums`, alone: a view of ``workspace``'s :data:`WINDOW_PARTS` buffer, over the
    counts' per-thread parts when there are several threads)."""
    workspace = scratch(workspace)
    threads = _threads(threads)
    expected = _window_buffers(workspace, threads, int(window_bounds(hood.windows)[-1]), len(hood.radii))[0]
    denominators = hood.denominators
    _expected_window_sums(hood.target_table, hood.colour, hood.side_px, hood.anchor, denominators.exact, denominators.slot,
                          denominators.values, unsigned(hood.member_offsets), unsigned(hood.member_window),
                          hood.member_weight, expected)
    return np.negative(_thread_total(expected), out=expected[0])


class FastObjective:
    """Objective and gradient for one neighbourhood, with buffers reused across iterations.

    ``threads``: parallel runs of points (at most numba's thread count); each
    run has its own window sums (``threads`` x W x m float32) and gradient part.
    Each pair keeps its bin and tent slope (6 bytes) from the window sums to the gradient of the same call.
    ``workspace``: where the buffers live (reused by the next refresh's objective).
    """

    def __init__(self, hood: Neighbourhoods, threads: int | None = None, workspace: Workspace | None = None):
        workspace = scratch(workspace)
        self.hood = hood
        n, m = len(hood.spacing), len(hood.radii)
        threads = _threads(threads)
        self.inv_width = 1.0 / float(hood.radii[1] - hood.radii[0])
        bounds = window_bounds(hood.windows)
        windows = bounds[-1]
        self.deviation = hood.deviation
        self.dead = np.concatenate([np.full(hi - lo, family.scale.dead_zone) for family, lo, hi in zip(hood.windows, bounds[:-1], bounds[1:])])
        self.scale = np.concatenate([np.full(hi - lo, family.scale.weight / ((hi - lo) * m))
                                     for family, lo, hi in zip(hood.windows, bounds[:-1], bounds[1:])])
        self.slot = hood.denominators.slot
        self.slope_x = np.ascontiguousarray(hood.expected_slope[..., 0])  # (K, m) each
        self.slope_y = np.ascontiguousarray(hood.expected_slope[..., 1])
        # the slopes cumulated over the radii (the gradient pairs them with dL/dS per radius, see _gradient)
        self.cumulative_x = cumulate(self.slope_x.astype(np.float64)).astype(self.slope_x.dtype)
        self.cumulative_y = cumulate(self.slope_y.astype(np.float64)).astype(self.slope_y.dtype)
        # the expected counts at the anchors do not move between refreshes: their window sums were taken once, by the
        # refresh (:func:`window_sums`; subtracted by _window_slopes)
        self.expected = hood.window_expected
        self.sums = _window_buffers(workspace, threads, windows, m)[1]  # past window_expected
        # each pair's bin (-1: out of reach or coincident) and tent slope / distance, written by every evaluation for
        # its gradient (6 bytes a pair: storing the offsets too, 10 bytes, was no faster)
        pairs = len(hood.neighbours)
        self.pair_bin = workspace.empty("objective.pair_bin", pairs, np.int16 if m < 2 ** 15 else np.int32)
        self.pair_pull = workspace.empty("objective.pair_pull", pairs, np.float32)
        self.slopes = workspace.empty("objective.slopes", (windows, m), np.float32)
        self.active = workspace.empty("objective.active", windows, np.bool_)
        self.losses = workspace.empty("objective.losses", windows)
        self.parts = workspace.empty("objective.parts", (threads, n, 2))
        # the variance force's loss term: the sloped points' anchors gathered once, their moves into a reused buffer
        # (the same products and sum as ``variance_force * (xy[sloped] - anchor[sloped])``; 10k points: 53 -> 9 us a call)
        self.sloped_anchor = hood.anchor[hood.sloped]
        self.moved = np.empty_like(self.sloped_anchor)
        self.window_sums_of_counts, self.gradient, _ = _kernels_for(m)
        self.indices = tuple(map(unsigned, (hood.offsets, hood.neighbours, hood.member_offsets, hood.member_window,
                                            self.pair_bin)))  # as the kernels take them

    def __call__(self, xy: np.ndarray, gradient: bool = True) -> tuple[float, np.ndarray | None]:
        """Objective and gradient (n, 2) (a reused buffer: copy it to keep it) at xy (n, 2) float64."""
        hood = self.hood
        counted = hood.anchor_counts  # the refresh's counts at the anchors, still in these buffers (see window_sums)
        hood.anchor_counts = None  # this call overwrites them, or consumes them
        if not (counted is not None and all(map(_same_array, counted, (self.sums, self.pair_bin, self.pair_pull)))
                and np.array_equal(xy, hood.anchor)):  # the same tent counts, bins and pulls (slope terms: 0 there)
            offsets, neighbours, member_offsets, member_window, pair_bin = self.indices
            self.window_sums_of_counts(xy, offsets, neighbours, hood.guide, hood.spacing, self.inv_width, hood.anchor,
                                       self.slot, self.slope_x, self.slope_y, member_offsets, member_window,
                                       hood.member_weight, self.sums, pair_bin, self.pair_pull, hood.guided)
        _window_slopes(self.sums, self.expected, self.deviation, self.dead, self.scale, self.slopes, self.losses,
                       self.active)
        loss = float(self.losses.sum())
        if len(hood.sloped):
            moved = np.take(xy, hood.sloped, axis=0, out=self.moved)
            loss += float(np.multiply(hood.variance_force, np.subtract(moved, self.sloped_anchor, out=moved), out=moved).sum())
        if not gradient:
            return loss, None
        offsets, neighbours, member_offsets, member_window, pair_bin = self.indices
        self.gradient(xy, offsets, neighbours, member_offsets, member_window, hood.member_weight, self.slopes,
                      self.active, self.slot, self.cumulative_x, self.cumulative_y, hood.variance_force, pair_bin,
                      self.pair_pull, self.parts)
        return loss, _thread_total(self.parts)  # the runs' parts summed into the first (each call zeroes them)
