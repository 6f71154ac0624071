"""What a pattern's own points tell ``infer``: the scale to read it at and the ink the map must hold.

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
2. **Ink the points hold** (:func:`calibrate_density`). The pattern holds
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

from export.gaussian import gaussian
from export.infer_config import DEFAULT_INFER, InferConfig
from synthesis.conventions import POINTS_PER_INK
from synthesis.points import PointSet


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
    blurred = gaussian(counts, sigma) / np.maximum(gaussian(area, sigma), 1e-9)
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


def calibrate_density(density: np.ndarray, mean_density: float) -> tuple[np.ndarray, float]:
    """((H, W) density ``min(s density, 1)``, the factor ``s``) with ``s`` making its mean ``mean_density``.

    ``density`` (H, W) in [0, 1], ``mean_density`` >= 0 (the pattern's ``n / (points_per_ink w h)``). When the mean
    cannot be reached (it would need more than full ink where the network put ink), full ink there, with ``s`` the
    smallest factor that gives it. A map without ink stays as it is (factor 1); ``mean_density`` 0 gives a white map
    (factor 0).

    The mean ``m(s) = mean(min(s density, 1))`` is piecewise linear, increasing and concave in ``s``, so Newton's
    method from ``mean_density / mean(density)`` (where ``m <= mean_density``) climbs to the root from below and
    lands on it exactly once it reaches the root's linear piece: a few passes over the map where bisection took 60
    (``tests/test_infer_evidence.py`` compares the two).
    """
    density = np.clip(np.asarray(density, np.float64), 0.0, 1.0)
    if mean_density <= 0:
        return np.zeros_like(density), 0.0
    if not (density > 0).any():
        return density, 1.0
    if mean_density * density.size >= np.count_nonzero(density):  # full ink wherever there is ink
        factor = 1.0 / float(density[density > 0].min())
        return np.minimum(factor * density, 1.0), factor
    factor = mean_density / float(density.mean())
    for _ in range(density.size):  # each step saturates more pixels: at most one step per pixel, a few in practice
        scaled = factor * density
        below = scaled < 1.0
        missing = mean_density - (np.count_nonzero(~below) + float(scaled[below].sum())) / density.size
        if missing <= 1e-12 * mean_density:
            break
        factor += missing * density.size / float(density[below].sum())
    return np.minimum(factor * density, 1.0), factor
