"""What a pattern's own local density tells ``infer``: the scale to read it at, and where correlation is not observable.

Two measurements on the points alone, before and after the network:

1. **Scale for dense patterns** (:func:`choose_points_per_ink`, when neither
   the user nor the point file's header gives it: :func:`pattern_scale`). Full
   ink (L = 0) holds ``points_per_ink`` points per unit area
   (:data:`synthesis.conventions.POINTS_PER_INK_MEANING`); a pattern denser than
   that somewhere cannot be read at the default 50,000 points per ink. The local density is a kernel density estimate on a grid
   whose cells hold ``scale_cell_points`` points at full ink (at
   the default scale), blurred by a Gaussian of ``scale_sigma_cells``
   cells. When its ``scale_quantile`` quantile exceeds
   ``scale_threshold``, the pattern is read at ``points_per_ink = default
   x quantile``, so that quantile reads as full ink; otherwise at the default,
   so ``infer`` then ``synthesize`` keeps the point count (the four constants are
   :class:`export.infer_config.InferConfig`'s, with the measurements that set them).
2. **Evidence for correlation** (:func:`local_evidence`). Correlation is a
   property of neighbourhoods: where a neighbourhood holds few points, no
   estimator sees it (below density 0.05-0.1 the network alone gives the
   same colour to every process). The evidence at a map pixel is the
   number of points within :data:`EVIDENCE_RADIUS_PX` pixels of the network's
   raster (a Gaussian window of the same area); it is *thin* below
   :data:`MIN_EVIDENCE_POINTS` (at the default model's 8,000 points per ink on
   256 px: density below about 0.1) and *empty* below
   :data:`EMPTY_EVIDENCE_POINTS`.
   :func:`fill_thin_correlation` replaces a, b where the evidence is thin by
   a normalised convolution (Knutsson and Westin 1993) of the well-observed
   a, b around it, widening the kernel until every such pixel has well-observed
   neighbours; L is never changed. A pixel without ink (density below
   :data:`INKED_DENSITY`) counts as unobserved too, whatever its window holds:
   its a, b only echoes the points around it (next to a half-empty pattern's
   edge, a zoomed reading sees that edge as a cluster's border and would paint
   the empty half red; filled, it takes the inked half's colour).
3. **Zoomed correlation** (:func:`correlation_zoom`). Correlation is a
   property of the pattern in units of its own spacing, density is not: a
   light area read as if the pattern held ``f`` times fewer points per ink
   shows the network the same arrangement at ``f`` times the density. Where
   the map's density is below :data:`WORK_DENSITY` (the density range where
   the network names the stationary processes right, ``bench/ood_*.md``), a, b
   come from such zoomed readings, ``f`` up to :data:`MAX_ZOOM`
   (:func:`export.runtime.infer_map`); their evidence is counted at the zoomed
   raster's scale, so thin means thin at the best zoom. Readings come at
   zooms 1, 2, 4 ... and a pixel blends the two around its zoom, so it never
   mixes in a reading at under half or over twice :data:`WORK_DENSITY`: the
   default network names all five stationary processes right at apparent
   densities 0.3-1.2 (measured with seed 7, not the evaluation's seed), while
   jitter read below 0.3 drifts towards step (zooms 1, 4, 16 around 0.4 would
   mix in readings at 0.1). A pixel is zoomed as the densest pixel
   within :data:`ZOOM_NEIGHBOURHOOD_PX` of it, so the light side of a density
   edge is read at the dark side's scale.
4. **Ink the points hold** (:func:`calibrate_density`). The pattern holds
   ``n`` points, so the map's mean density must be ``n / (points_per_ink w h)``
   (``synthesize``'s count): one factor over the network's ink restores it,
   water-filled under full ink. No points, no ink: the network cannot invent
   any. (The ink is not capped where a pixel's disc holds no point: a
   clustered pattern's voids would then read as light areas, confusing
   clustering with density.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter, maximum_filter

from export.infer_config import DEFAULT_INFER, InferConfig
from synthesis.conventions import POINTS_PER_INK
from synthesis.labmap import LabMap
from synthesis.points import PointSet

EVIDENCE_RADIUS_PX = 12.0  # neighbourhood of the correlation evidence, in pixels of the network raster
MIN_EVIDENCE_POINTS = 6.0  # fewer points in it: correlation is not observable (thin)
EMPTY_EVIDENCE_POINTS = 0.5  # fewer: no points at all near the pixel (empty)
FILL_SIGMAS_PX = (4.0, 8.0, 16.0, 32.0, 64.0, 128.0, 256.0)  # normalised-convolution kernels tried, map pixels
FILL_MIN_WEIGHT = 0.02  # mean confidence under a kernel needed to fill from it
INKED_DENSITY = 0.01  # below this density a pixel's own a, b does not count (no pattern there to read); fully from twice it
WORK_DENSITY = 0.6  # correlation is read where the apparent density reaches this (the default network is reliable at 0.3-1.2)
ZOOM_STEP = 2  # zoomed readings at f = 2, 4, ... 64, so a blend of two never reads below WORK_DENSITY / 2 or above twice it
MAX_ZOOM = 64  # at most this zoom (a raster 8 times smaller)
ZOOM_NEIGHBOURHOOD_PX = 4  # map pixels: a pixel is zoomed as the densest pixel this near


@dataclass(frozen=True)
class ScaleChoice:
    """The points per ink a pattern is read at.

    Attributes:
        points_per_ink: points per unit area of full ink (the synthesiser's ``n = points_per_ink x w x h x mean density``).
        automatic: chosen by :func:`choose_points_per_ink` (False: given by the user or the file's header).
        local_density_quantile: the ``quantile`` quantile of the local density at the default scale
            (1 = a fully dark map); None when the scale was given.
        origin: who gave a scale that is not automatic (``"given"``: the user; ``"from the file's header"``).
        quantile: the quantile taken (:attr:`export.infer_config.InferConfig.scale_quantile`).
    """

    points_per_ink: float
    automatic: bool
    local_density_quantile: float | None = None
    origin: str = "given"
    quantile: float = DEFAULT_INFER.scale_quantile

    def describe(self) -> str:
        """One line for the user, e.g. ``80,000 points per ink (automatic: ...)``."""
        if not self.automatic:
            return f"{self.points_per_ink:,.0f} points per ink ({self.origin})"
        quantile = f"{100 * self.quantile:g}th-percentile local density {self.local_density_quantile:.2f}"
        return f"{self.points_per_ink:,.0f} points per ink (automatic: {quantile} of a fully dark map at the default)"

    def report(self) -> dict:
        return {"points_per_ink": round(self.points_per_ink, 1), "automatic": self.automatic,
                "local_density_quantile": None if self.local_density_quantile is None else round(self.local_density_quantile, 4)}


def local_density(points: PointSet, points_per_ink: float, config: InferConfig = DEFAULT_INFER) -> np.ndarray:
    """(rows, cols) kernel density estimate of ``points`` in map units (1 = a fully dark map at ``points_per_ink``).

    Grid cells are squares of side ``sqrt(config.scale_cell_points / points_per_ink)`` covering the domain,
    blurred by ``config.scale_sigma_cells`` cells; the blur reflects at the domain's border.
    """
    w, h = points.domain
    cells, sigma = config.scale_cell_points, config.scale_sigma_cells
    cell = math.sqrt(cells / points_per_ink)
    cols, rows = max(1, math.ceil(w / cell)), max(1, math.ceil(h / cell))
    counts, _, _ = np.histogram2d(points.xy[:, 1], points.xy[:, 0], bins=(rows, cols), range=((0, rows * cell), (0, cols * cell)))
    inside = np.clip(np.array([h / cell, w / cell]) - np.array([rows - 1, cols - 1]), 0.0, 1.0)  # last row/col's share in the domain
    area = np.ones((rows, cols))
    area[-1, :] *= inside[0]
    area[:, -1] *= inside[1]
    blurred = gaussian_filter(counts, sigma, mode="reflect") / np.maximum(gaussian_filter(area, sigma, mode="reflect"), 1e-9)
    return blurred / cells


def pattern_scale(points: PointSet, points_per_ink: float | None = None, config: InferConfig = DEFAULT_INFER) -> ScaleChoice:
    """The scale ``infer`` and ``convert`` read ``points`` at: ``points_per_ink`` when given, else the one the
    point file's header records (:attr:`synthesis.points.PointSet.points_per_ink`), else
    :func:`choose_points_per_ink` from the default :data:`synthesis.conventions.POINTS_PER_INK`."""
    if points_per_ink is not None:
        return ScaleChoice(points_per_ink, False)
    if points.points_per_ink is not None:
        return ScaleChoice(points.points_per_ink, False, origin="from the file's header")
    return choose_points_per_ink(points, POINTS_PER_INK, config)


def choose_points_per_ink(points: PointSet, default: float, config: InferConfig = DEFAULT_INFER) -> ScaleChoice:
    """The points per ink to read ``points`` at: ``default`` unless the pattern is denser (see the module docstring)."""
    if len(points) == 0:
        return ScaleChoice(default, True, 0.0, quantile=config.scale_quantile)
    quantile = float(np.quantile(local_density(points, default, config), config.scale_quantile))
    scale = default * quantile if quantile > config.scale_threshold else default
    return ScaleChoice(scale, True, quantile, quantile=config.scale_quantile)


def local_evidence(points: PointSet, shape: tuple[int, int], raster_pixels_per_unit: float) -> np.ndarray:
    """(H, W) expected number of points within :data:`EVIDENCE_RADIUS_PX` raster pixels of each map pixel.

    ``shape`` is the map's (H, W) over ``points.domain``; ``raster_pixels_per_unit`` the network raster's
    pixels per unit of the domain (:func:`export.runtime.raster_scale`). A Gaussian window of the disc's area;
    near the border, the count in its part inside the domain scaled to the whole window (so a light area
    reads thin, not a corner of a well-observed one).
    """
    height, width = shape
    w, h = points.domain
    pixel = w / width
    counts, _, _ = np.histogram2d(points.xy[:, 1], points.xy[:, 0], bins=(height, width), range=((0, height * pixel), (0, w)))
    radius = EVIDENCE_RADIUS_PX / raster_pixels_per_unit / pixel  # map pixels
    sigma = radius / math.sqrt(2.0)  # 2 pi sigma^2 = pi r^2
    inside = gaussian_filter(np.ones((height, width)), sigma, mode="constant")
    return gaussian_filter(counts, sigma, mode="constant") / np.maximum(inside, 1e-9) * (2.0 * math.pi * sigma * sigma)


@dataclass(frozen=True)
class EvidenceSummary:
    """Shares of a map's pixels by their correlation evidence (:func:`local_evidence`), each in [0, 1].

    Attributes:
        thin_share: some points near the pixel, but fewer than :data:`MIN_EVIDENCE_POINTS`.
        empty_share: no points near it (fewer than :data:`EMPTY_EVIDENCE_POINTS`).
        filled: whether a, b of these pixels were filled from their surroundings.
        fill_source: False when no pixel of the map had enough evidence to fill from.
    """

    thin_share: float
    empty_share: float
    filled: bool
    fill_source: bool

    def report(self) -> dict:
        return {"thin_evidence_share": round(self.thin_share, 4), "empty_share": round(self.empty_share, 4),
                "min_evidence_points": MIN_EVIDENCE_POINTS, "evidence_radius_raster_px": EVIDENCE_RADIUS_PX,
                "filled_from_surroundings": self.filled, "well_observed_area": self.fill_source}


def confidence(evidence: np.ndarray) -> np.ndarray:
    """Weight in [0, 1] of the network's a, b: 0 below :data:`MIN_EVIDENCE_POINTS`, 1 from twice that, linear between."""
    return np.clip(np.asarray(evidence, np.float64) / MIN_EVIDENCE_POINTS - 1.0, 0.0, 1.0)


def ink_weight(density: np.ndarray) -> np.ndarray:
    """Weight in [0, 1] of a pixel's own a, b by its density (H, W) in [0, 1]: 0 below :data:`INKED_DENSITY`, 1 from
    twice that, linear between. An area without ink has no pattern to read: its a, b only echoes the points around it."""
    return np.clip(np.asarray(density, np.float64) / INKED_DENSITY - 1.0, 0.0, 1.0)


def fill_thin_correlation(lab_map: LabMap, evidence: np.ndarray) -> tuple[LabMap, bool]:
    """(map with a, b blended towards the surrounding well-observed a, b, whether any source existed).

    ``a, b <- c a, b + (1 - c) NC(a, b)`` with ``c`` = :func:`confidence` of the evidence times :func:`ink_weight`
    (the evidence's alone when no pixel reaches :data:`INKED_DENSITY`: a map that light has no inked area to
    fill from) and ``NC`` the normalised convolution ``G * (c ab) / G * c`` at the smallest kernel of
    :data:`FILL_SIGMAS_PX` whose mean confidence reaches :data:`FILL_MIN_WEIGHT` at the pixel. Without a
    well-observed pixel the map is returned unchanged.
    """
    observed = confidence(evidence)
    weight = observed * ink_weight(lab_map.density())
    if not weight.any():
        weight = observed
    if not weight.any():
        return lab_map, False
    ab = lab_map.ab.astype(np.float64)
    filled = ab.copy()
    pending = weight < 1.0
    for sigma in FILL_SIGMAS_PX:
        if not pending.any():
            break
        denominator = gaussian_filter(weight, sigma, mode="constant", truncate=3.0)
        ready = pending & (denominator >= FILL_MIN_WEIGHT)
        if ready.any():
            for channel in range(2):
                numerator = gaussian_filter(weight * ab[..., channel], sigma, mode="constant", truncate=3.0)
                filled[..., channel][ready] = numerator[ready] / denominator[ready]
            pending &= ~ready
    blended = weight[..., None] * ab + (1.0 - weight[..., None]) * filled
    return LabMap(np.concatenate([lab_map.lab[..., :1], blended.astype(np.float32)], axis=-1)), True


def summarise(evidence: np.ndarray, filled: bool, fill_source: bool) -> EvidenceSummary:
    """Shares of thin and empty pixels of an evidence map (H, W)."""
    empty = evidence < EMPTY_EVIDENCE_POINTS
    thin = ~empty & (evidence < MIN_EVIDENCE_POINTS)
    return EvidenceSummary(float(thin.mean()), float(empty.mean()), filled, fill_source)


def correlation_zoom(density: np.ndarray) -> np.ndarray:
    """(H, W) zoom ``f`` in [1, MAX_ZOOM] at which each pixel's density (H, W) in [0, 1] reads as :data:`WORK_DENSITY`.

    A pixel's density is taken as the densest within :data:`ZOOM_NEIGHBOURHOOD_PX` of it, so a light pixel next to
    a dark area is read at the dark area's scale: zoomed, such a density edge looks like a cluster's border.
    """
    local = maximum_filter(np.asarray(density, np.float64), size=2 * ZOOM_NEIGHBOURHOOD_PX + 1, mode="nearest")
    return np.clip(WORK_DENSITY / np.maximum(local, WORK_DENSITY / MAX_ZOOM), 1.0, MAX_ZOOM)


def zoom_levels(zoom: np.ndarray) -> tuple[int, ...]:
    """The zoomed readings needed for a zoom map: 1, ZOOM_STEP, ZOOM_STEP^2 ... up to the largest zoom wanted."""
    largest = float(np.max(zoom)) if np.size(zoom) else 1.0
    levels = [1]
    while levels[-1] < largest - 1e-9 and levels[-1] < MAX_ZOOM:
        levels.append(levels[-1] * ZOOM_STEP)
    return tuple(levels)


def blend_zoomed(zoom: np.ndarray, levels: tuple[int, ...], readings: list[np.ndarray]) -> np.ndarray:
    """(H, W, ...) per-pixel interpolation in log zoom between the readings (each (H, W, ...)) at ``levels``."""
    if len(levels) == 1:
        return readings[0]
    position = np.clip(np.log(zoom) / math.log(ZOOM_STEP), 0.0, len(levels) - 1.0)  # 0 at zoom 1, 1 at ZOOM_STEP ...
    lower = np.minimum(np.floor(position).astype(int), len(levels) - 2)
    upper_weight = position - lower
    stack = np.stack(readings)  # (levels, H, W, ...)
    rows, cols = np.indices(zoom.shape)
    low, high = stack[lower, rows, cols], stack[lower + 1, rows, cols]
    weight = upper_weight.reshape(upper_weight.shape + (1,) * (stack.ndim - 3))
    return (1.0 - weight) * low + weight * high


def calibrate_density(density: np.ndarray, mean_density: float) -> tuple[np.ndarray, float]:
    """((H, W) density ``min(s density, 1)``, the factor ``s``) with ``s`` making its mean ``mean_density``.

    ``density`` (H, W) in [0, 1], ``mean_density`` >= 0 (the pattern's ``n / (points_per_ink w h)``). When the mean
    cannot be reached (the mean would need more than full ink where the network put ink), full ink there.
    A map without ink stays as it is (factor 1); ``mean_density`` 0 gives a white map (factor 0).
    """
    density = np.clip(np.asarray(density, np.float64), 0.0, 1.0)
    if mean_density <= 0:
        return np.zeros_like(density), 0.0
    if not (density > 0).any():
        return density, 1.0

    def mean_at(factor: float) -> float:
        return float(np.minimum(factor * density, 1.0).mean())

    low, high = 0.0, 1.0
    while mean_at(high) < mean_density and high < 1e12:
        low, high = high, high * 4.0
    for _ in range(60):  # bisection: the mean is continuous and non-decreasing in the factor
        middle = 0.5 * (low + high)
        low, high = (middle, high) if mean_at(middle) < mean_density else (low, middle)
    return np.minimum(high * density, 1.0), high
