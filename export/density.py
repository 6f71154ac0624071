"""A point pattern as a raster of counts per map pixel (:func:`count_raster`; ``patternshop_nn.ood``'s KDE baselines)."""

from __future__ import annotations

import numpy as np

from synthesis.raster import point_raster


def count_raster(xy_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) points per pixel, splatted bilinearly (sums kept), of points (n, 2) in map pixel coordinates."""
    side = max(shape)
    return point_raster(np.asarray(xy_px, np.float64) / side, side, clip=False)[:shape[0], :shape[1]].astype(np.float64)
