"""Content-aware fill of a map's hole: multi-scale PatchMatch synthesis (the counterpart of Photoshop's
Content-Aware Fill in the paper's Fig. 9, pattern expansion).

The hole is filled with more of the known map's texture, not with a smooth continuation: every
``patch`` x ``patch`` patch that touches the hole is matched to a patch lying wholly in the known
region (its nearest neighbour in the sum of squared L, a, b differences), and each hole pixel becomes
what the best-matching patch covering it proposes (the EM scheme of Wexler, Shechtman and Irani 2007,
"Space-Time Completion of Video", with the sharpest vote: a weighted mean blurs the grain and lost on
bench/bench_fill.py). Matches are found with PatchMatch (Barnes et al. 2009):
propagation from the four neighbouring patches, one random source anywhere, and a random search in
a window halving from the whole map. This runs coarse to fine on a pyramid of 2x2 means, the
coarsest level at least ``coarsest`` pixels a side, so large structures (clearings, forest edges)
continue and the finer levels add the grain. The coarsest hole starts as a random tiling of known
patches (edge repetition's streaks or a flat colour are local minima the EM keeps); each finer level
starts from the coarser one's matches, drawn at twice the size by a mean vote.
L, a and b are matched and filled jointly, so correlation regions continue with the texture.

Shapes and ranges: maps are (H, W, 3) float32 CIELAB (L in [0, 100], a, b in [-128, 127]); a hole
is an (H, W) bool mask, True where pixels are to be filled. Filled pixels are convex combinations of
known ones, so they stay in range. Nearest-neighbour fields are (N, 2) int32 top-left corners (row,
column) of the source patch for target patch i at (ty[i], tx[i]).

:mod:`synthesis.patchfill_fast` has the numba kernels; :func:`search_reference` and
:func:`vote_reference` are their plain numpy versions, which tests compare them against.
"""

from __future__ import annotations

import numpy as np

from synthesis import patchfill_fast as fast
from synthesis.errors import PatternshopError

PATCH = 7  # patch side, pixels
COARSEST = 32  # the coarsest level's short side is at least this, pixels
ITERATIONS = (8, 2)  # EM iterations (match, vote) at the coarsest and the finest level, linear in between
PASSES = 2  # PatchMatch passes per EM iteration


def _patch_distances(image: np.ndarray, patch: int, ty: np.ndarray, tx: np.ndarray, sy: np.ndarray,
                     sx: np.ndarray) -> np.ndarray:
    """(n,) float64 sums of squared differences of the patches at (ty, tx) and at (sy, sx), summed in the kernel's order."""
    total = np.zeros(len(ty))
    for dy in range(patch):
        for dx in range(patch):
            for c in range(image.shape[2]):
                d = image[ty + dy, tx + dx, c].astype(np.float64) - image[sy + dy, sx + dx, c].astype(np.float64)
                total += d * d
    return total


def search_reference(image: np.ndarray, patch: int, ty: np.ndarray, tx: np.ndarray, tid: np.ndarray, valid: np.ndarray,
                     sources: np.ndarray, nnf_in: np.ndarray, dist_in: np.ndarray, key: int, nnf_out: np.ndarray,
                     dist_out: np.ndarray) -> None:
    """One PatchMatch pass over all target patches at once (Jacobi: every target reads ``nnf_in``), into ``nnf_out``.

    Args:
        image: (H, W, 3) float32 map, the hole holding the current guess.
        patch: patch side p; patch positions (top-left corners) form a (H - p + 1, W - p + 1) grid.
        ty, tx: (N,) int32 positions of the target patches (those touching the hole).
        tid: (H - p + 1, W - p + 1) int32 index of the target patch at each position, -1 for source patches.
        valid: (H - p + 1, W - p + 1) bool, True where the patch lies wholly in the known region.
        sources: (S,) x 2 int32 positions where ``valid``, row-major.
        nnf_in, dist_in: (N, 2) int32 matches and (N,) float64 their distances before the pass.
        key: in [0, 2^32), the pass's random stream.
        nnf_out, dist_out: written: each target's best of its match, its neighbours' matches shifted
            back by one step, one random source and a random search around the best so far.
    """
    positions_y, positions_x = valid.shape
    index = np.arange(len(ty), dtype=np.int64)
    best_y, best_x, best = nnf_in[:, 0].astype(np.int64), nnf_in[:, 1].astype(np.int64), dist_in.astype(np.float64)

    def consider(cy: np.ndarray, cx: np.ndarray, ok: np.ndarray) -> None:
        d = np.full(len(ty), np.inf)
        d[ok] = _patch_distances(image, patch, ty[ok], tx[ok], cy[ok], cx[ok])
        better = d < best
        best_y[better], best_x[better], best[better] = cy[better], cx[better], d[better]

    def is_source(cy: np.ndarray, cx: np.ndarray) -> np.ndarray:
        inside = (cy >= 0) & (cy < positions_y) & (cx >= 0) & (cx < positions_x)
        return inside & valid[np.clip(cy, 0, positions_y - 1), np.clip(cx, 0, positions_x - 1)]

    for dy, dx in fast.NEIGHBOURS:
        ny, nx = ty.astype(np.int64) + dy, tx.astype(np.int64) + dx
        inside = (ny >= 0) & (ny < positions_y) & (nx >= 0) & (nx < positions_x)
        neighbour = np.where(inside, tid[np.clip(ny, 0, positions_y - 1), np.clip(nx, 0, positions_x - 1)], -1)
        cy = nnf_in[np.maximum(neighbour, 0), 0].astype(np.int64) - dy
        cx = nnf_in[np.maximum(neighbour, 0), 1].astype(np.int64) - dx
        consider(cy, cx, (neighbour >= 0) & is_source(cy, cx))
    pick = (fast.uniform.py_func(key, index, 0) * len(sources)).astype(np.int64)
    consider(sources[pick, 0].astype(np.int64), sources[pick, 1].astype(np.int64), np.ones(len(ty), bool))
    radius, slot = max(positions_y, positions_x), 1
    while radius >= 1:
        cy = np.clip(best_y + np.floor((2.0 * fast.uniform.py_func(key, index, slot) - 1.0) * radius + 0.5).astype(np.int64),
                     0, positions_y - 1)
        cx = np.clip(best_x + np.floor((2.0 * fast.uniform.py_func(key, index, slot + 1) - 1.0) * radius + 0.5).astype(np.int64),
                     0, positions_x - 1)
        consider(cy, cx, valid[cy, cx])
        radius //= 2
        slot += 2
    nnf_out[:, 0], nnf_out[:, 1], dist_out[:] = best_y, best_x, best


def vote_reference(image: np.ndarray, patch: int, hy: np.ndarray, hx: np.ndarray, tid: np.ndarray, nnf: np.ndarray,
                   weight: np.ndarray, sharp: bool, out: np.ndarray) -> None:
    """One vote: ``out`` (M, 3) float32 for the hole pixels (hy, hx) (M,) from the target patches covering each (``tid``,
    ``nnf`` as in :func:`search_reference`): the pixel at the same place in their matches, ``weight`` (N,) float64-ed.

    ``sharp`` False: the weighted mean (weights > 0); True: the value proposed by the covering patch of largest weight
    (the first in (dy, dx) scan order on ties), which keeps the texture's grain where a mean would blur it.
    """
    positions_y, positions_x = tid.shape
    acc = np.zeros((len(hy), image.shape[2]))
    total = np.zeros(len(hy))
    top = np.full(len(hy), -np.inf)
    for dy in range(patch):
        for dx in range(patch):
            y, x = hy.astype(np.int64) - dy, hx.astype(np.int64) - dx
            inside = np.nonzero((y >= 0) & (y < positions_y) & (x >= 0) & (x < positions_x))[0]
            t = tid[y[inside], x[inside]]
            w = weight[t]
            proposal = image[nnf[t, 0] + dy, nnf[t, 1] + dx].astype(np.float64)
            if sharp:
                better = w > top[inside]
                acc[inside[better]], top[inside[better]], total[inside[better]] = proposal[better], w[better], 1.0
            else:
                for c in range(image.shape[2]):
                    acc[inside, c] += w * proposal[:, c]
                total[inside] += w
    out[:] = acc / total[:, None]


def _distances_reference(image: np.ndarray, patch: int, ty: np.ndarray, tx: np.ndarray, nnf: np.ndarray,
                         out: np.ndarray) -> None:
    out[:] = _patch_distances(image, patch, ty, tx, nnf[:, 0], nnf[:, 1])


def _pyramid(lab: np.ndarray, hole: np.ndarray, patch: int, coarsest: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(image, hole) per level, finest first: 2x2 means (edges repeated on odd sides); a coarse pixel is in the hole
    if any of its fine pixels is. Stops before a level shorter than ``coarsest`` or without a whole known patch."""
    levels = [(lab, hole)]
    while True:
        image, mask = levels[-1]
        height, width = mask.shape
        if min((height + 1) // 2, (width + 1) // 2) < coarsest:
            return levels
        padding = ((0, height % 2), (0, width % 2))
        image = np.pad(image, padding + ((0, 0),), mode="edge")
        mask = np.pad(mask, padding, mode="edge")
        image = image.reshape(image.shape[0] // 2, 2, image.shape[1] // 2, 2, 3).mean(axis=(1, 3), dtype=np.float64)
        mask = mask.reshape(mask.shape[0] // 2, 2, mask.shape[1] // 2, 2).any(axis=(1, 3))
        if not _known_patches(mask, patch).any():
            return levels
        levels.append((image.astype(np.float32), mask))


def _known_patches(hole: np.ndarray, patch: int) -> np.ndarray:
    """(H - p + 1, W - p + 1) bool: True where the p x p patch (top-left corner there) has no hole pixel."""
    counts = np.pad(hole.astype(np.int64).cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    window = counts[patch:, patch:] - counts[:-patch, patch:] - counts[patch:, :-patch] + counts[:-patch, :-patch]
    return window == 0


def _random_sources(sources: np.ndarray, key: int, count: int) -> np.ndarray:
    """(count, 2) int32: a source position per target, from the hash stream ``key``."""
    return sources[(fast.uniform.py_func(key, np.arange(count, dtype=np.int64), 0) * len(sources)).astype(np.int64)]


def _random_tiling(known: np.ndarray, hole: np.ndarray, sources: np.ndarray, patch: int, key: int) -> np.ndarray:
    """(H, W, 3) float32: ``known`` with the hole tiled by p x p blocks copied from random source patches (``key``'s
    hash stream): a start with the known texture's local statistics, neither streaks nor a flat colour."""
    hy, hx = np.nonzero(hole)
    block = (hy // patch) * (-(-hole.shape[1] // patch)) + hx // patch
    source = sources[(fast.uniform.py_func(key, block.astype(np.int64), 0) * len(sources)).astype(np.int64)]
    image = known.copy()
    image[hy, hx] = known[source[:, 0] + hy % patch, source[:, 1] + hx % patch]
    return image


def content_aware_fill(lab: np.ndarray, hole: np.ndarray, *, seed: int = 0, patch: int = PATCH, coarsest: int = COARSEST,
                       iterations: tuple[int, int] = ITERATIONS, passes: int = PASSES, reference: bool = False) -> np.ndarray:
    """(H, W, 3) float32: ``lab`` with the pixels where ``hole`` is True filled with its known region's texture.

    Args:
        lab: (H, W, 3) CIELAB map; the values in the hole are ignored.
        hole: (H, W) bool, True where to fill; the known pixels are returned unchanged.
        seed: the fill is a deterministic function of the inputs and the seed.
        patch: patch side in pixels (odd or even, >= 2); the known region must hold a whole patch.
        coarsest: the coarsest pyramid level's short side, pixels (at least; fewer levels if the hole leaves no
            known patch there).
        iterations: EM iterations at the coarsest and at the finest level.
        passes: PatchMatch passes per EM iteration.
        reference: run the numpy references instead of the numba kernels (slow; for tests).

    Raises:
        PatternshopError: shapes disagree, the map is smaller than a patch, or no patch lies wholly in the known region.
    """
    lab = np.asarray(lab, np.float32)
    hole = np.asarray(hole, bool)
    if lab.ndim != 3 or lab.shape[2] != 3 or hole.shape != lab.shape[:2]:
        raise PatternshopError(f"content-aware fill needs an (H, W, 3) map and an (H, W) hole, got {lab.shape} and {hole.shape}")
    if patch < 2 or min(hole.shape) < patch:
        raise PatternshopError(f"content-aware fill needs a map of at least {patch}x{patch} px and patches of >= 2 px, "
                               f"got {hole.shape[1]}x{hole.shape[0]} px and patch {patch}")
    if not hole.any():
        return lab.copy()
    if not _known_patches(hole, patch).any():
        raise PatternshopError(f"content-aware fill needs a known {patch}x{patch} px patch to copy from: "
                               "the hole leaves none")
    search, vote, distances = ((search_reference, vote_reference, _distances_reference) if reference
                               else (fast.search, fast.vote, fast.distances))
    rng = np.random.default_rng(seed)
    levels = _pyramid(lab, hole, patch, coarsest)
    schedule = np.rint(np.linspace(iterations[0], iterations[1], len(levels))).astype(int)
    image = nnf = positions = None
    for level, ((known, mask), count) in enumerate(zip(reversed(levels), schedule, strict=True)):
        valid = _known_patches(mask, patch)
        ty, tx = (v.astype(np.int32) for v in np.nonzero(~valid))
        tid = np.full(valid.shape, -1, np.int32)
        tid[ty, tx] = np.arange(len(ty), dtype=np.int32)
        sources = np.argwhere(valid).astype(np.int32)
        hy, hx = (v.astype(np.int32) for v in np.nonzero(mask))
        start = _random_sources(sources, int(rng.integers(2**32)), len(ty))
        if level == 0:
            image = _random_tiling(known, mask, sources, patch, int(rng.integers(2**32)))
        else:  # the coarser level's result and matches, at twice the size
            coarse, coarse_nnf, coarse_tid = image, nnf, positions
            image = known.copy()
            image[hy, hx] = coarse[hy // 2, hx // 2]
            cy, cx = np.minimum(ty // 2, coarse_tid.shape[0] - 1), np.minimum(tx // 2, coarse_tid.shape[1] - 1)
            parent = coarse_tid[cy, cx]
            sy = np.where(parent >= 0, 2 * coarse_nnf[np.maximum(parent, 0), 0] + ty % 2, -1)
            sx = np.where(parent >= 0, 2 * coarse_nnf[np.maximum(parent, 0), 1] + tx % 2, -1)
            inside = (sy >= 0) & (sy < valid.shape[0]) & (sx >= 0) & (sx < valid.shape[1])
            ok = inside & valid[np.clip(sy, 0, valid.shape[0] - 1), np.clip(sx, 0, valid.shape[1] - 1)]
            start[ok] = np.stack([sy[ok], sx[ok]], axis=1)
        image = np.ascontiguousarray(image, np.float32)
        nnf, spare = np.ascontiguousarray(start, np.int32), np.empty_like(start, np.int32)
        dist, spare_dist, out = np.empty(len(ty)), np.empty(len(ty)), np.empty((len(hy), 3), np.float32)
        if level > 0:  # the upsampled matches draw the finer level's detail before any search
            vote(image, patch, hy, hx, tid, nnf, np.ones(len(ty)), False, out)
            image[hy, hx] = out
        for _ in range(count):
            distances(image, patch, ty, tx, nnf, dist)
            for _ in range(passes):
                search(image, patch, ty, tx, tid, valid, sources, nnf, dist, int(rng.integers(2**32)), spare, spare_dist)
                nnf, spare, dist, spare_dist = spare, nnf, spare_dist, dist
            vote(image, patch, hy, hx, tid, nnf, -dist, True, out)
            image[hy, hx] = out
        positions = tid
    result = lab.copy()
    result[hole] = image[hole]
    return result
