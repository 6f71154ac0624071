"""Points as a raster of counts per map pixel (patternshop_nn.baselines.count_raster, the KDE baselines of patternshop_nn.ood)."""

from __future__ import annotations

import numpy as np
import pytest

from patternshop_nn.baselines import count_raster


def test_count_raster_keeps_the_points_of_a_non_square_map() -> None:
    xy = np.array([[0.1, 0.05], [0.9, 0.3], [0.5, 0.45]])  # on a 1 x 0.5 domain, 64 map pixels per unit
    raster = count_raster(xy * 64, (32, 64))
    assert raster.shape == (32, 64) and raster.sum() == pytest.approx(3.0)
    assert raster[:, 54:56].sum() == pytest.approx(0.0) and raster[18:21, 56:59].sum() == pytest.approx(1.0)  # (57.6, 19.2)
