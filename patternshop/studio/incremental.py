"""Local re-synthesis after an edit: keep the points away from what changed, re-make only the changed window.

Edits are local, so after an edit the studio does not synthesise the whole map again. It compares the current
map with the map of the last finished synthesis (the *base*: every edit, undo and redo since then is in that
difference, and an undo back to the base's map leaves none) and plans a :class:`LocalUpdate`:

* **region**: the changed pixels dilated by :data:`REGION_SPACINGS` spacings (of the new map's density around the
  change, in this and the next two); the base's points in it are
  dropped and new ones drawn there: the window's own density-matched start for the new map's count
  (:func:`synthesis.synthesize.redrawn_start`, stratified where the target is regular), its points in the region;
* **band**: the region dilated by :data:`BAND_SPACINGS` more; the kept points there are refined too (they
  meet the new points);
* **window**: the band's bounding box widened by :data:`CONTEXT_SPACINGS` more (clipped to the map): the map
  crop the synthesiser warm-starts on (``start_points``), with every point in it; after the run, points
  outside the band take their base positions back (they were context: the window's edge is a border to the
  synthesiser), so every point away from the edit is exactly the base's.

The run costs what the window holds, not the map. A change covering more than :data:`MAX_WINDOW_SHARE` of the
map (measured: see docs/studio.md), another seed or point setting, another canvas size, or no base at all
mean a full synthesis (:func:`plan_local_update` returns None).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from synthesis.labmap import LabMap, pixels_of

REGION_SPACINGS = 2.0  # the changed pixels dilated by this many local spacings: points re-drawn there
BAND_SPACINGS = 3.0  # the region dilated by this many more: kept points refined with the new ones
CONTEXT_SPACINGS = 4.0  # the band's box widened by this many more: points the refinement sees but does not keep
MAX_WINDOW_SHARE = 0.5  # a window over this share of the map's area: a full synthesis instead (docs/studio.md)
SPARSE_FLOOR = 0.1  # the spacing around a change: densities below this share of the mean count as this (a cap)


@dataclass(frozen=True)
class Base:
    """A finished synthesis the next one may start from: the (H, W, 3) map it was made of (never changed in
    place), its (n, 2) points in map units, its seed and what decided its point count (``("points", n)`` or
    ``("ink", points_per_ink)``)."""

    lab: np.ndarray
    xy: np.ndarray
    seed: int
    count_key: tuple


@dataclass(frozen=True)
class LocalUpdate:
    """A planned local re-synthesis (see the module docstring); positions in map units unless said otherwise."""

    window: LabMap  # the crop of the new map the synthesiser runs on (its own domain, long side 1)
    box: tuple[int, int, int, int]  # the window in map pixels: (y0, y1, x0, x1)
    side_px: int  # the map's long side, pixels
    fixed: np.ndarray  # (f, 2) base points outside the window: kept as they are
    start: np.ndarray  # (k, 2) the window's start points, in map units: kept base points, then the new ones
    refined: np.ndarray  # (k,) bool: the run's position is kept (the band); else the start's
    drawn: int  # how many of ``start`` are new (the last ones)
    iterations: int  # of the run on the window: the whole schedule (a re-drawn region is a fresh start)
    changed_share: float  # share of the map's pixels that changed
    window_share: float  # share of the map's area the window covers

    @property
    def n(self) -> int:
        """Points in the result."""
        return len(self.fixed) + len(self.start)

    def to_window(self, xy: np.ndarray) -> np.ndarray:
        """(k, 2) map units (of points in the window) -> the window's units (clipped to its domain: rounding)."""
        y0, y1, x0, x1 = self.box
        return np.clip((xy * self.side_px - (x0, y0)) / max(y1 - y0, x1 - x0), 0.0, self.window.domain)

    def to_map(self, xy: np.ndarray) -> np.ndarray:
        """(k, 2) the window's units -> map units."""
        y0, y1, x0, x1 = self.box
        return (xy * max(y1 - y0, x1 - x0) + (x0, y0)) / self.side_px

    def frame(self, window_xy: np.ndarray) -> np.ndarray:
        """(n, 2) the whole map's points while the window's (k, 2) run is at ``window_xy`` (its units, any order)."""
        return np.concatenate([self.fixed, self.to_map(window_xy)])

    def run(self, seed: int, on_iteration: Callable[[int, np.ndarray], None] | None = None) -> tuple[np.ndarray, int]:
        """Warm-start the synthesiser on the window; returns ((n, 2) the result in map units, iterations run).
        ``on_iteration(done, xy)`` sees the whole map's (n, 2) points (:meth:`frame`) as they form."""
        from synthesis.synthesize import synthesize

        start = self.to_window(self.start)
        if len(start) < 2:  # nothing to refine
            return self.merge(start), 0
        forward = None if on_iteration is None else (lambda done, xy: on_iteration(done, self.frame(xy)))
        result = synthesize(self.window, seed=seed, start_points=start, iterations=self.iterations,
                            on_iteration=forward)
        return self.merge(result.points.xy), result.iterations

    def merge(self, window_xy: np.ndarray) -> np.ndarray:
        """(n, 2) the result: the fixed points, the run's (k, 2) final positions (window units, the start's order)
        in the band, the start's elsewhere."""
        inside = np.where(self.refined[:, None], self.to_map(window_xy), self.start)
        return np.concatenate([self.fixed, inside])


def changed_pixels(before: np.ndarray, after: np.ndarray) -> np.ndarray | None:
    """(H, W) bool: pixels whose L, a or b differ between two (H, W, 3) maps; None when their sizes differ."""
    if before.shape != after.shape:
        return None
    return np.any(before != after, axis=2)


def _box(mask: np.ndarray, reach: int) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1): the bounding box of the (H, W) bool ``mask`` (not all False) widened by ``reach`` pixels,
    clipped to the mask."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return (max(0, rows[0] - reach), min(mask.shape[0], rows[-1] + reach + 1),
            max(0, cols[0] - reach), min(mask.shape[1], cols[-1] + reach + 1))


def _dilate(mask: np.ndarray, radius: float) -> np.ndarray:
    """(H, W) bool: pixels within ``radius`` pixels (Euclidean, centre to centre) of ``mask``, computed on the
    mask's bounding box widened by the radius."""
    from scipy import ndimage  # not at import: the server's start would pay 0.2 to 0.4 s for it

    y0, y1, x0, x1 = _box(mask, int(math.ceil(radius)))
    out = np.zeros_like(mask)
    out[y0:y1, x0:x1] = ndimage.distance_transform_edt(~mask[y0:y1, x0:x1]) <= radius
    return out


def plan_local_update(base: Base, lab: np.ndarray, n: int, seed: int, count_key: tuple,
                      max_window_share: float = MAX_WINDOW_SHARE) -> LocalUpdate | None:
    """How to re-make ``n`` points (the new map's count at the base's points per ink) for the (H, W, 3) map
    ``lab`` from ``base`` locally (the result holds about ``n``), or None for a full synthesis: no change, another
    size, seed or count setting, or a window over ``max_window_share`` of the map (see the module docstring)."""
    from synthesis.synthesize import SCHEDULES, redrawn_start

    changed = changed_pixels(base.lab, lab)
    if changed is None or seed != base.seed or tuple(count_key) != tuple(base.count_key) or not changed.any():
        return None
    height, width = lab.shape[:2]
    side_px = max(height, width)
    density = np.clip(1.0 - lab[..., 0].astype(np.float64) / 100.0, 0.0, 1.0)
    mean_spacing_px = math.sqrt(height * width / n)
    ring = _dilate(changed, REGION_SPACINGS * mean_spacing_px) & ~changed  # the points next to the change
    around = float(density[ring].mean()) if ring.any() else float(density.mean())
    spacing_px = mean_spacing_px / math.sqrt(max(around / max(float(density.mean()), 1e-12), SPARSE_FLOOR))
    region = _dilate(changed, REGION_SPACINGS * spacing_px)
    band = _dilate(region, BAND_SPACINGS * spacing_px)
    y0, y1, x0, x1 = _box(band, int(math.ceil(CONTEXT_SPACINGS * spacing_px)))
    window_share = (y1 - y0) * (x1 - x0) / (height * width)
    if window_share > max_window_share:
        return None
    row, col = pixels_of(base.xy, (height, width))
    dropped = region[row, col]
    in_window = (row >= y0) & (row < y1) & (col >= x0) & (col < x1)
    window_map = LabMap(np.ascontiguousarray(lab[y0:y1, x0:x1]))
    window_ink = float(density[y0:y1, x0:x1].sum())
    window_n = round(n * window_ink / max(float(density.sum()), 1e-30))  # the new map's count, for the window
    new_points = np.empty((0, 2))
    if window_n >= 2:  # the window's own density-matched start, its points in the region
        side_window = max(y1 - y0, x1 - x0)
        inside = redrawn_start(window_map, np.empty((0, 2)), region[y0:y1, x0:x1], seed, window_n)
        new_points = (inside * side_window + (x0, y0)) / side_px
    kept = in_window & ~dropped
    start = np.concatenate([base.xy[kept], new_points])
    refined = np.concatenate([band[row[kept], col[kept]], np.ones(len(new_points), bool)])
    return LocalUpdate(window_map, (int(y0), int(y1), int(x0), int(x1)), side_px,
                       base.xy[~in_window], start, refined, len(new_points), SCHEDULES["fast"].iterations,
                       float(changed.mean()), float(window_share))
