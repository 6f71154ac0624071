"""L smoothed as far as its predicted uncertainty allows: the smoothing ladder of ``infer``.

A model with an ``l_scale`` output (:class:`export.runtime.OnnxModel`) predicts, per pixel, the Laplace scale
``b`` of its density: its expected absolute error (density units, 0..1). Where the density is flat but grainy,
smoothing it changes it by about its noise, within ``b``; across an edge or a texture the network is sure
of, smoothing changes it by much more than ``b``. :func:`smooth_by_uncertainty` climbs a ladder of Gaussian
smoothings (:func:`smoothing_levels`: 1, 2, 4 ... px) and lets each pixel take the next level while the change
that level makes, averaged over a window, stays within ``k`` (:attr:`export.infer_config.InferConfig.smoothing_tolerance`)
times the predicted scale averaged the same way: wide in flat areas, not across edges.

:func:`smoothing_ladder` is the ladder itself, given how far each level may change the density. Its Gaussians
are scipy's filter as float32 matrix products (:func:`export.gaussian.gaussian`; 13 ms a 256-px map against 27-29
ms through numpy's FFT in float64, the same widths within 2e-5 px).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from export.gaussian import gaussian
from export.infer_config import DEFAULT_INFER, InferConfig


def smoothing_levels(shape: tuple[int, int], config: InferConfig = DEFAULT_INFER) -> tuple[float, ...]:
    """Gaussian widths in px of the ladder on a map (H, W): ``config.smoothing_start_px``, doubling, up to
    ``config.smoothing_max_fraction`` of its long side (1, 2, 4 ... 16 on 256 px)."""
    levels = [config.smoothing_start_px]
    while 2 * levels[-1] <= config.smoothing_max_fraction * max(shape):
        levels.append(2 * levels[-1])
    return tuple(levels)


def smoothing_window(level: float, config: InferConfig = DEFAULT_INFER) -> float:
    """Gaussian window (px) over which a level's change is compared with what it may change."""
    return max(config.smoothing_min_window_px, config.smoothing_window * level)


def smoothing_ladder(density: np.ndarray, excess: Callable[[float, np.ndarray], np.ndarray],
                     config: InferConfig = DEFAULT_INFER) -> tuple[np.ndarray, np.ndarray]:
    """(density (H, W), smoothing width (H, W) in px): ``density`` (H, W) smoothed level by level.

    ``excess(level, smoothed)`` gives (H, W) the change the Gaussian smoothing of width ``level`` makes
    (``smoothed`` is the density smoothed so) over the change it may make: a pixel takes the level below 1,
    not above, fading over 1 +- ``config.smoothing_softness``. A level refused stops the wider ones. The ink
    is not restored (the caller water-fills).
    """
    density = np.asarray(density, np.float64)
    result, width = density.copy(), np.zeros(density.shape)
    taken, previous, previous_level = np.ones(density.shape), density, 0.0
    softness = config.smoothing_softness
    for level in smoothing_levels(density.shape, config):
        smooth = gaussian(density, level)
        taken = taken * np.clip((1.0 + softness - excess(level, smooth)) / (2.0 * softness), 0.0, 1.0)
        result += taken * (smooth - previous)
        width += taken * (level - previous_level)
        previous, previous_level = smooth, level
    return result, width


def smooth_by_uncertainty(density: np.ndarray, scale: np.ndarray, config: InferConfig = DEFAULT_INFER
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(density (H, W), smoothing width (H, W) in px): ``density`` (H, W) in [0, 1] smoothed where its change
    stays within ``config.smoothing_tolerance`` times ``scale`` (H, W) >= 0, its predicted Laplace scale (density
    units), both averaged over :func:`smoothing_window` (see the module docstring). Scale 0 everywhere: only
    what smoothing does not change (a flat map) is smoothed."""
    density = np.asarray(density, np.float64)
    scale = np.maximum(np.asarray(scale, np.float64), 0.0)
    allowed: dict[float, np.ndarray] = {}  # per window: levels up to 4 px share the smallest

    def excess(level: float, smooth: np.ndarray) -> np.ndarray:
        window = smoothing_window(level, config)
        if window not in allowed:
            allowed[window] = config.smoothing_tolerance * gaussian(scale, window, config.smoothing_window_truncate)
        change = gaussian(np.abs(density - smooth), window, config.smoothing_window_truncate)
        return change / np.maximum(allowed[window], 1e-12)

    return smoothing_ladder(density, excess, config)
