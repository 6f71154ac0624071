"""The fidelity bench's statistics (bench/fidelity_stats.py) on processes whose answer is known."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
import fidelity_stats as fs  # noqa: E402


def hex_lattice(m: int, k: int, a: float = 1.0) -> tuple[np.ndarray, tuple[float, float]]:
    """m x k points of a hexagonal lattice of spacing a, periodic in a (m a) x (k a sqrt(3)/2) domain (k even)."""
    rows, cols = np.mgrid[0:k, 0:m]
    x = (cols + 0.5 * (rows % 2) + 0.25) * a
    y = (rows + 0.5) * a * math.sqrt(3) / 2
    return np.stack([x.ravel(), y.ravel()], 1), (m * a, k * a * math.sqrt(3) / 2)


def test_r_max_is_the_hexagonal_spacing():
    xy, domain = hex_lattice(40, 30, a=0.01)
    assert fs.r_max(len(xy), domain[0] * domain[1]) == pytest.approx(0.01)


@pytest.mark.parametrize("periodic", [False, True])
def test_poisson_pcf_is_one_from_r_zero(periodic):
    rng = np.random.default_rng(0)
    curves = [fs.pcf(rng.random((3000, 2)), periodic=periodic)[1] for _ in range(6)]
    g = np.mean(curves, axis=0)
    r = fs.pcf(rng.random((10, 2)))[0]
    assert r[0] == 0 and r[-1] == pytest.approx(2.5)
    assert abs(g[r >= 0.5].mean() - 1) < 0.02
    assert np.all(np.abs(g[r >= 0.5] - 1) < 0.15)
    assert abs(g[r < 0.2].mean() - 1) < 0.25  # finite and unbiased at small r (annulus normalisation)


def test_translation_correction_removes_the_border_bias():
    """Few points in a bounded window: without the correction g(2.5 r_max) would read ~10 % low."""
    rng = np.random.default_rng(1)
    g = np.mean([fs.pcf(rng.random((400, 2)))[1] for _ in range(40)], axis=0)
    assert abs(g[-20:].mean() - 1) < 0.04


def test_lattice_pcf_and_nearest_neighbours():
    xy, domain = hex_lattice(40, 30, a=0.01)
    r, g = fs.pcf(xy, domain, periodic=True)
    assert g[r < 0.7].max() < 1e-6  # nothing closer than the spacing (kernel tails aside)
    assert r[np.argmax(g)] == pytest.approx(1.0, abs=0.03)
    stats = fs.nn_stats(xy, fs.Intensity.constant(len(xy), domain), periodic=True)
    assert stats["nn_cv"] < 1e-6
    assert stats["min_nn"] == pytest.approx(1.0)
    assert stats["stacked_fraction"] == 0


def test_poisson_nn_cv_and_stacked_share():
    """Poisson: NN distance is Rayleigh (CV = sqrt(4/pi - 1) = 0.523); P(NN < 0.05 r_max) = 1 - exp(-lambda pi (0.05 r_max)^2)."""
    rng = np.random.default_rng(2)
    n = 20000
    stats = fs.nn_stats(rng.random((n, 2)), fs.Intensity.constant(n), periodic=True)
    assert stats["nn_cv"] == pytest.approx(math.sqrt(4 / math.pi - 1), abs=0.015)
    expected = 1 - math.exp(-math.pi * 0.05**2 * 4 / (2 * math.sqrt(3)))
    assert stats["stacked_fraction"] == pytest.approx(expected, abs=0.003)


def test_stacked_points_are_counted_and_min_nn_is_zero():
    xy, domain = hex_lattice(40, 30, a=0.01)
    stacked = np.concatenate([xy, xy[:12] + 1e-7])
    stats = fs.nn_stats(stacked, fs.Intensity.constant(len(stacked), domain), periodic=True)
    assert stats["stacked_count"] == 24
    assert stats["min_nn"] < 1e-4


def test_bounded_nn_cv_uses_minus_sampling():
    """A bounded window of a torus pattern has the same NN CV as the torus itself."""
    rng = np.random.default_rng(3)
    xy = rng.random((8000, 2))
    intensity = fs.Intensity.constant(len(xy))
    assert fs.nn_stats(xy, intensity)["nn_cv"] == pytest.approx(fs.nn_stats(xy, intensity, periodic=True)["nn_cv"], abs=0.02)


def test_local_units_follow_the_density():
    """The same lattice read against a uniform density of 0.3 or of 1 gives the same local statistics."""
    xy, domain = hex_lattice(40, 30, a=0.01)
    flat = fs.Intensity(np.full((8, 8), 0.3), domain, len(xy))
    assert flat.local_r_max(xy[:5]) == pytest.approx(np.full(5, 0.01))
    assert fs.nn_stats(xy, flat, periodic=True)["min_nn"] == pytest.approx(1.0)


def test_empty_circles_lattice_and_a_hole():
    xy, domain = hex_lattice(60, 60, a=1 / 60)
    intensity = fs.Intensity.constant(len(xy), domain)
    lattice = fs.empty_circles(xy, intensity, periodic=True)
    assert lattice["largest"] == pytest.approx(1 / math.sqrt(3), abs=0.01)  # circumradius of the lattice triangle
    assert lattice["holes"] == 0
    centre = np.array([domain[0] / 2, domain[1] / 2])
    holed = xy[np.hypot(*(xy - centre).T) > 3.2 / 60]
    result = fs.empty_circles(holed, fs.Intensity.constant(len(holed), domain), periodic=True)
    assert 3.2 < result["largest"] < 4.2  # a hole of radius ~3.5 spacings (in units of the new, slightly larger r_max)
    assert result["holes"] == 1
    assert np.hypot(*(np.array(result["largest_at"]) - centre)) < 1 / 60


def test_empty_circles_ignore_light_regions_and_the_border():
    rng = np.random.default_rng(4)
    density = np.ones((32, 32))
    density[:, :16] = 0.05  # light left half: not counted
    n = 3000
    x = rng.random(n)
    keep = (x > 0.5) | (rng.random(n) < 0.05)
    xy = np.stack([x, rng.random(n)], 1)[keep]
    result = fs.empty_circles(xy, fs.Intensity(density, (1.0, 1.0), len(xy)))
    assert result["largest_at"][0] > 0.5
    assert result["largest"] < 2.5  # Poisson-like holes, not the light half


def test_poisson_disk_reference_and_lloyd_stippler():
    pd = fs.poisson_disk(1000, 0)
    assert abs(len(pd) - 1000) < 40
    assert fs.nn_stats(pd, fs.Intensity.constant(len(pd)))["min_nn"] >= 0.72
    density = np.full((64, 64), 0.7)
    xy = fs.lloyd_stipple(density, 400, iterations=40, seed=0)
    assert len(xy) == 400 and xy.min() >= 0 and xy.max() <= 1
    stats = fs.nn_stats(xy, fs.Intensity(density, (1.0, 1.0), 400))
    assert stats["nn_cv"] < 0.15 and stats["min_nn"] > 0.4  # regular (pixel-grid centroids are quantised)


def test_capacity_constrained_lloyd_gives_every_point_its_ink():
    from data_gen.stipplers import capacity_lloyd_stipple

    y, x = (np.mgrid[0:96, 0:96] + 0.5) / 96
    density = np.where(x < 0.5, 0.2, 0.9) * (0.8 + 0.2 * np.cos(6 * y))
    density[:8, :8] = 0.0  # paper: a cell there must not swallow ink (it once took 36 capacities)
    n = 600
    xy, spread = capacity_lloyd_stipple(density, n, iterations=30, seed=0)
    assert spread < 0.5  # pixel-discrete: a pixel is ~n / 9216 = 0.07 of a capacity
    lloyd = fs.lloyd_stipple(density, n, iterations=30, seed=0)
    assert np.sum(xy[:, 0] > 0.5) / n == pytest.approx(density[:, 48:].sum() / density.sum(), abs=0.01)
    assert fs.density_psnr(xy, density, (1.0, 1.0), 2.0) > fs.density_psnr(lloyd, density, (1.0, 1.0), 2.0) + 3


def test_density_psnr_prefers_the_right_density():
    rng = np.random.default_rng(5)
    density = np.tile(np.linspace(0.05, 1.0, 128), (128, 1))
    n = 20000
    p = density.ravel() / density.sum()
    pixel = rng.choice(density.size, n, p=p)
    row, col = np.divmod(pixel, 128)
    matched = (np.stack([col, row], 1) + rng.random((n, 2))) / 128
    uniform = rng.random((n, 2))
    lloyd = fs.lloyd_stipple(density, n // 4, iterations=30, seed=0)
    good = fs.density_psnr(matched, density, (1.0, 1.0), 2.0)
    assert good > fs.density_psnr(uniform, density, (1.0, 1.0), 2.0) + 10
    assert fs.density_psnr(matched, density, (1.0, 1.0), 2.0) > fs.density_psnr(matched, density, (1.0, 1.0), 1.0)
    assert fs.density_psnr(lloyd, density, (1.0, 1.0), 2.0) > 25


def test_border_and_strip_profiles():
    rng = np.random.default_rng(6)
    n = 20000
    xy = rng.random((n, 2))
    _, ratio = fs.border_profile(xy, (1.0, 1.0), n)
    assert np.all(np.abs(ratio - 1) < 0.12)
    clamped = xy.copy()
    unit = fs.r_max(n, 1.0)
    clamped[:200, 0] = 0.0  # 200 points clamped onto the left border
    _, ratio = fs.border_profile(clamped, (1.0, 1.0), n)
    assert ratio[0] > 1.5
    centres, strips = fs.strip_profile(xy[:, 0] - 0.5, n * 1.0, unit, -3, 3)
    assert len(centres) == 12 and np.all(np.abs(strips - 1) < 0.2)


def test_density_psnr_of_a_lattice_is_high():
    """A hexagonal lattice on a constant map: no moiré from the rasteriser, no border artefact."""
    rows, cols = np.mgrid[0:152, 0:132]
    a = 1 / 132
    xy = np.stack([((cols + 0.5 * (rows % 2) + 0.25) * a).ravel(), ((rows + 0.5) * a * math.sqrt(3) / 2).ravel()], 1)
    density = np.full((512, 512), 0.7)
    assert fs.density_psnr(xy, density, (1.0, 1.0), 1.0) > 35
    assert fs.density_psnr(xy, density, (1.0, 1.0), 2.0) > 38
