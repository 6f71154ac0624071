"""export.gaussian: scipy.ndimage.gaussian_filter (mode 'reflect') as matrix products and through numpy's FFT, against
scipy's own."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from export.gaussian import MATRIX_MAX_SIDE, gaussian, gaussian_fft
from helpers import fresh_python_lines


SIGMAS = ((0.1, 4.0), (1.0, 4.0), (2.5, 4.0), (4.0, 4.0), (8.0, 2.0), (16.0, 4.0), (16.0, 2.0), (32.0, 2.0), (64.0, 4.0))


@pytest.mark.parametrize("shape", [(256, 256), (200, 256), (96, 40), (35, 36), (3, 40), (1, 7), (1, 1)])
def test_gaussians_are_scipys(shape: tuple[int, int]) -> None:
    """Narrow kernels, wide ones, kernels wider than the map (scipy's reflection repeated) and radius 0: the FFT
    reference to rounding, the float32 matrix products to 1e-6 of the map's range (values up to 50, as counts)."""
    image = np.random.default_rng(4).random(shape) ** 3
    for sigma, truncate in SIGMAS:
        scipys = gaussian_filter(image, sigma, truncate=truncate)
        message = f"sigma {sigma}, truncate {truncate}"
        np.testing.assert_allclose(gaussian_fft(image, sigma, truncate), scipys, rtol=0, atol=1e-14, err_msg=message)
        np.testing.assert_allclose(gaussian(image, sigma, truncate), scipys, rtol=0, atol=1e-6, err_msg=message)
        np.testing.assert_allclose(gaussian(50 * image, sigma, truncate), 50 * scipys, rtol=0, atol=5e-5, err_msg=message)


def test_large_maps_go_through_the_fft() -> None:
    """Past MATRIX_MAX_SIDE the products would cost more than the FFT (n^3 against n^2 log n): the reference runs."""
    image = np.random.default_rng(5).random((MATRIX_MAX_SIDE + 1, 9))
    assert np.array_equal(gaussian(image, 3.0), gaussian_fft(image, 3.0))
    assert not np.array_equal(gaussian(image[:MATRIX_MAX_SIDE], 3.0), gaussian_fft(image[:MATRIX_MAX_SIDE], 3.0))


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
