"""Numba kernels of :mod:`synthesis.patchfill`: one PatchMatch pass and one vote (same maths, same results).

Both are Jacobi steps, parallel over their outputs: a pass reads the previous nearest-neighbour
field and writes a new one, a vote reads the field and writes the hole's pixels, so no two threads
write one element and the result does not depend on the thread count. Random numbers come from a
counter-based hash (:func:`uniform`) of (key, target, slot), so the numpy references
(:func:`synthesis.patchfill.search_reference`, :func:`synthesis.patchfill.vote_reference`) draw the
same ones; tests compare the two.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_JIT = {"parallel": True, "cache": True, "fastmath": False}
NEIGHBOURS = ((0, -1), (0, 1), (-1, 0), (1, 0))  # (dy, dx) of the patches whose matches propagate


@numba.njit(cache=True)
def lowbias32(x):  # pragma: no cover - jitted
    """A 32-bit integer hash (C. Wellons' lowbias32) of x in [0, 2^32), int64 scalar or array; wrapping products."""
    x = x ^ (x >> 16)
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x = x ^ (x >> 15)
    x = (x * 0x846CA68B) & 0xFFFFFFFF
    return x ^ (x >> 16)


@numba.njit(cache=True)
def uniform(key, index, slot):  # pragma: no cover - jitted
    """A uniform number in [0, 1) for (key in [0, 2^32), index in [0, 2^32), slot >= 0): scalars or int64 arrays."""
    return lowbias32(lowbias32(key ^ index) ^ (slot + 1)) / 4294967296.0


@numba.njit(cache=True, inline="always")
def _distance(image, patch, ty, tx, sy, sx, bound):  # pragma: no cover - jitted
    """Sum of squared differences (float64) of the patches at (ty, tx) and (sy, sx); stops once a row reaches bound."""
    total = 0.0
    for dy in range(patch):
        for dx in range(patch):
            for c in range(image.shape[2]):
                d = np.float64(image[ty + dy, tx + dx, c]) - np.float64(image[sy + dy, sx + dx, c])
                total += d * d
        if total >= bound:
            return total
    return total


@numba.njit(**_JIT)
def search(image, patch, ty, tx, tid, valid, sources, nnf_in, dist_in, key, nnf_out, dist_out):  # pragma: no cover - jitted
    """One PatchMatch pass (see :func:`synthesis.patchfill.search_reference` for the arguments)."""
    positions_y, positions_x = valid.shape
    for i in numba.prange(len(ty)):
        y, x = ty[i], tx[i]
        best_y, best_x, best = nnf_in[i, 0], nnf_in[i, 1], dist_in[i]
        for k in range(4):  # propagation: a neighbour's match, shifted back by the step to it
            dy, dx = NEIGHBOURS[k]
            ny, nx = y + dy, x + dx
            if 0 <= ny < positions_y and 0 <= nx < positions_x and tid[ny, nx] >= 0:
                cy, cx = nnf_in[tid[ny, nx], 0] - dy, nnf_in[tid[ny, nx], 1] - dx
                if 0 <= cy < positions_y and 0 <= cx < positions_x and valid[cy, cx]:
                    d = _distance(image, patch, y, x, cy, cx, best)
                    if d < best:
                        best_y, best_x, best = cy, cx, d
        pick = int(uniform(key, i, 0) * len(sources))  # one source anywhere
        cy, cx = sources[pick, 0], sources[pick, 1]
        d = _distance(image, patch, y, x, cy, cx, best)
        if d < best:
            best_y, best_x, best = cy, cx, d
        radius, slot = max(positions_y, positions_x), 1
        while radius >= 1:  # random search around the best so far, the window halving
            cy = min(max(best_y + int(math.floor((2.0 * uniform(key, i, slot) - 1.0) * radius + 0.5)), 0), positions_y - 1)
            cx = min(max(best_x + int(math.floor((2.0 * uniform(key, i, slot + 1) - 1.0) * radius + 0.5)), 0), positions_x - 1)
            if valid[cy, cx]:
                d = _distance(image, patch, y, x, cy, cx, best)
                if d < best:
                    best_y, best_x, best = cy, cx, d
            radius //= 2
            slot += 2
        nnf_out[i, 0], nnf_out[i, 1], dist_out[i] = best_y, best_x, best


@numba.njit(**_JIT)
def distances(image, patch, ty, tx, nnf, out):  # pragma: no cover - jitted
    """out[i] = full patch distance of target i to its match nnf[i] (no early stop)."""
    for i in numba.prange(len(ty)):
        out[i] = _distance(image, patch, ty[i], tx[i], nnf[i, 0], nnf[i, 1], np.inf)


@numba.njit(**_JIT)
def vote(image, patch, hy, hx, tid, nnf, weight, sharp, out):  # pragma: no cover - jitted
    """One vote (see :func:`synthesis.patchfill.vote_reference` for the arguments)."""
    positions_y, positions_x = tid.shape
    channels = image.shape[2]
    for m in numba.prange(len(hy)):
        acc = np.zeros(channels)
        total = 0.0
        top = -np.inf
        for dy in range(patch):
            for dx in range(patch):
                y, x = hy[m] - dy, hx[m] - dx
                if 0 <= y < positions_y and 0 <= x < positions_x:
                    t = tid[y, x]
                    w = weight[t]
                    if sharp:
                        if w > top:
                            top = w
                            for c in range(channels):
                                acc[c] = np.float64(image[nnf[t, 0] + dy, nnf[t, 1] + dx, c])
                            total = 1.0
                        continue
                    for c in range(channels):
                        acc[c] += w * np.float64(image[nnf[t, 0] + dy, nnf[t, 1] + dx, c])
                    total += w
        for c in range(channels):
            out[m, c] = acc[c] / total
