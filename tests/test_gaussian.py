"""export.gaussian: scipy.ndimage.gaussian_filter (mode 'reflect') through numpy's FFT, against scipy's own."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from export.gaussian import gaussian
from helpers import fresh_python_lines


@pytest.mark.parametrize("shape", [(256, 256), (200, 256), (96, 40), (35, 36), (3, 40), (1, 7), (1, 1)])
def test_fft_gaussian_is_scipys(shape: tuple[int, int]) -> None:
    """Narrow kernels, wide ones, kernels wider than the map (scipy's reflection repeated) and radius 0."""
    image = np.random.default_rng(4).random(shape) ** 3
    for sigma, truncate in ((0.1, 4.0), (1.0, 4.0), (2.5, 4.0), (4.0, 4.0), (8.0, 2.0), (16.0, 4.0), (16.0, 2.0),
                            (32.0, 2.0), (64.0, 4.0)):
        np.testing.assert_allclose(gaussian(image, sigma, truncate), gaussian_filter(image, sigma, truncate=truncate),
                                   rtol=0, atol=1e-14, err_msg=f"sigma {sigma}, truncate {truncate}")


def test_infer_imports_no_scipy(tmp_path: Path) -> None:
    """``infer``'s whole path (scale, network, smoothing, water-filling, writing) runs without importing scipy,
    whose import was a fifth of a 20,000-point ``infer`` (export/gaussian.py)."""
    points = tmp_path / "points.txt"
    rng = np.random.default_rng(0)
    np.savetxt(points, rng.random((3000, 2)), header="domain 1 1", comments="# ")
    code = ("import sys\n"
            "from patternshop.cli import main\n"
            f"status = main(['infer', {str(points)!r}, {str(tmp_path / 'map.tif')!r}, '--threads', '1'])\n"
            "print(status, sorted(m for m in sys.modules if m == 'scipy' or m.startswith('scipy.')))\n")
    assert fresh_python_lines(code)[-1] == "0 []"
