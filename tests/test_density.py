"""L from the points where they are regular (export.density): Clark-Evans ratio, two-guide filter, sharpening;
L smoothed where its detail is noise: Poisson resampling and scale selection."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from scipy.stats import qmc

from data_gen.stipplers import lloyd_stipple, random_stipple
from export.density import (POISSON_RATIO, REGULAR_RATIO, SHARP_BANDWIDTH, clark_evans_ratio, count_raster, denoise_density,
                            map_points, poisson_resample, regularity_weight, sharpen_density, spacing_kde, two_guide_filter)
from export.uncertainty import smoothing_levels
from synthesis.generators import generate
from synthesis.points import PointSet

SIZE = 128


def interior_ratio(xy_unit: np.ndarray) -> float:
    """Median Clark-Evans ratio over a map's interior for points (n, 2) of a stationary pattern on the unit square."""
    density = np.full((SIZE, SIZE), 1.0)
    ratio = clark_evans_ratio(map_points(PointSet(xy_unit), density.shape), density, len(xy_unit) / density.size, 4.0)
    return float(np.median(ratio[16:-16, 16:-16]))


def test_clark_evans_ratio_tells_regular_from_poisson_and_clustered_points() -> None:
    poisson = interior_ratio(generate("white", 8_000, seed=1))
    disk = qmc.PoissonDisk(2, radius=0.0085, seed=2).fill_space()
    regular = interior_ratio(disk)
    clustered = interior_ratio(generate("red", 8_000, seed=3))
    assert abs(poisson - 1.0) < 0.1, poisson
    assert regular > REGULAR_RATIO, (regular, len(disk))
    assert clustered < 0.8, clustered
    assert regularity_weight(np.array([poisson])) < 0.1 and regularity_weight(np.array([regular])) == 1.0
    assert regularity_weight(np.array([POISSON_RATIO])) == 0.0 and regularity_weight(np.array([REGULAR_RATIO])) == 1.0


def test_clark_evans_ratio_needs_two_points() -> None:
    density = np.ones((8, 8))
    assert not clark_evans_ratio(np.array([[3.0, 3.0]]), density, 1.0, 2.0).any()


def test_two_guide_filter_keeps_a_noise_free_source_and_follows_the_guide_under_noise() -> None:
    rng = np.random.default_rng(0)
    guide = np.full((64, 64), 0.2)
    guide[:, 32:] = 0.8
    clean = 2.0 * guide + 0.1
    source = clean + 0.05 * rng.standard_normal((64, 64))
    np.testing.assert_allclose(two_guide_filter(source, guide, np.zeros_like(source), 2.0), source, atol=1e-6)
    noisy = two_guide_filter(source, guide, np.full_like(source, 1e3), 2.0)
    edge = slice(29, 35)
    assert np.abs(noisy - clean).mean() < 0.5 * np.abs(source - clean).mean()
    assert np.abs(noisy - clean)[:, edge].mean() < 0.2 * np.abs(gaussian_filter(source, 2.0) - clean)[:, edge].mean()
    flat = two_guide_filter(np.full((32, 32), 0.4), guide[:32, 16:48], np.full((32, 32), 0.01), 2.0)
    np.testing.assert_allclose(flat, 0.4, atol=1e-9)


def step_density() -> np.ndarray:
    """(SIZE, SIZE) density 0.2 on the left half, 0.8 on the right."""
    density = np.full((SIZE, SIZE), 0.2)
    density[:, SIZE // 2:] = 0.8
    return density


@pytest.mark.parametrize("stippler", ["lloyd", "random"])
def test_sharpening_restores_edges_of_regular_stipplings_and_leaves_poisson_ones_to_the_network(stippler: str) -> None:
    truth = step_density()
    points_per_ink = 20_000.0
    n = round(points_per_ink * truth.mean())
    if stippler == "lloyd":
        xy = lloyd_stipple(np.kron(truth, np.ones((2, 2))), n, iterations=30, seed=5)
    else:
        xy = random_stipple(truth, n, (1.0, 1.0), np.random.default_rng(5))
    network = gaussian_filter(truth, 4.0)  # what a reader at a fixed bandwidth of a few spacings gives
    sharpened, weight = sharpen_density(PointSet(xy), network, points_per_ink)
    share = weight.mean()
    edge = slice(SIZE // 2 - 6, SIZE // 2 + 6)
    if stippler == "lloyd":
        assert share > 0.9
        assert np.abs(sharpened - truth)[:, edge].mean() < 0.6 * np.abs(network - truth)[:, edge].mean()
    else:
        assert share < 0.1
        assert np.abs(sharpened - network).mean() < 0.01


def test_sharpening_is_a_no_op_below_two_points() -> None:
    density = np.full((16, 16), 0.01)
    for xy in (np.zeros((0, 2)), np.array([[0.5, 0.5]])):
        same, weight = sharpen_density(PointSet(xy), density, 50_000.0)
        assert weight.shape == density.shape and not weight.any() and np.array_equal(same, density)


def test_count_raster_keeps_the_points_of_a_non_square_map() -> None:
    points = PointSet(np.array([[0.1, 0.05], [0.9, 0.3], [0.5, 0.45]]), (1.0, 0.5))
    raster = count_raster(map_points(points, (32, 64)), (32, 64))
    assert raster.shape == (32, 64) and raster.sum() == pytest.approx(3.0)


def test_two_guide_filter_is_finite_where_the_source_is_empty() -> None:
    source = np.zeros((32, 32))
    source[:, :8] = 0.5
    guide = np.linspace(0.0, 1.0, 32)[None, :].repeat(32, 0)
    out = two_guide_filter(source, guide, np.full_like(source, 0.01), 2.0)
    assert np.isfinite(out).all() and np.abs(out[:, 20:]).max() < 1e-6


def test_spacing_kde_keeps_the_points_and_shows_no_dots_in_light_areas() -> None:
    """In a light regular pattern the points are several pixels apart: a kernel as wide as the full-ink spacing
    shows each as a dot, one as wide as the local spacing does not."""
    full_ink_per_px = 1.0
    density = np.full((SIZE, SIZE), 0.1)
    xy = lloyd_stipple(np.ones((2 * SIZE, 2 * SIZE)), round(0.1 * SIZE * SIZE), iterations=30, seed=2) * SIZE
    estimate, width = spacing_kde(xy, density, full_ink_per_px)
    np.testing.assert_allclose(width, SHARP_BANDWIDTH / np.sqrt(0.1))
    assert estimate.sum() * full_ink_per_px == pytest.approx(len(xy), rel=1e-6)
    inner = (slice(8, -8), slice(8, -8))
    fixed = gaussian_filter(count_raster(xy, density.shape), SHARP_BANDWIDTH) / full_ink_per_px
    assert np.std(estimate[inner]) / np.mean(estimate[inner]) < 0.1 < 0.25 < np.std(fixed[inner]) / np.mean(fixed[inner])


def test_smoothing_levels_double_up_to_a_sixteenth_of_the_long_side() -> None:
    assert smoothing_levels((256, 256)) == (1.0, 2.0, 4.0, 8.0, 16.0)
    assert smoothing_levels((64, 512)) == (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
    assert smoothing_levels((8, 8)) == (1.0,)


def test_poisson_resample_draws_the_smoothed_density_within_its_pixels() -> None:
    density = np.zeros((64, 96))
    density[:, 48:] = 0.5
    full_ink_per_px = 4.0
    xy = poisson_resample(density, full_ink_per_px, np.random.default_rng(0))
    expected = density.sum() * full_ink_per_px
    assert abs(len(xy) - expected) < 4 * np.sqrt(expected)
    assert (xy >= 0).all() and (xy[:, 0] < 96).all() and (xy[:, 1] < 64).all()
    assert (xy[:, 0] < 40).mean() < 0.001  # the empty half stays empty beyond the 2-px smoothing of its edge
    again = poisson_resample(density, full_ink_per_px, np.random.default_rng(0))
    np.testing.assert_array_equal(xy, again)


def noisy(truth: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(truth + correlated noise, an independent sample of that noise), each shaped like ``truth``."""
    rng = np.random.default_rng(seed)
    grain = lambda: gaussian_filter(rng.normal(0.0, 0.12, truth.shape), 1.5)  # noise with a few pixels' grain
    return truth + grain(), grain()


def test_denoising_smooths_a_flat_area_wide() -> None:
    truth = np.full((SIZE, SIZE), 0.4)
    reading, noise = noisy(truth, 1)
    denoised, width = denoise_density(reading, noise)
    assert np.median(width) == pytest.approx(8.0)  # the widest level on 128 px
    assert np.std(denoised) < 0.45 * np.std(reading)  # what an 8-px blur leaves of this noise on 128 px: 0.34


def test_denoising_keeps_the_edge_that_a_global_smoothing_blurs() -> None:
    truth = step_density()
    reading, noise = noisy(truth, 2)
    denoised, width = denoise_density(reading, noise)
    blurred = gaussian_filter(reading, 4.0)
    edge = (slice(16, -16), slice(SIZE // 2 - 3, SIZE // 2 + 3))
    assert np.abs(denoised - truth)[edge].mean() < 0.5 * np.abs(blurred - truth)[edge].mean()
    assert np.abs(denoised - truth).mean() < 0.7 * np.abs(reading - truth).mean()
    assert width[:, SIZE // 2 - 2:SIZE // 2 + 2].mean() < 1.0 < width[:, :16].mean()


def test_denoising_keeps_detail_the_noise_cannot_explain() -> None:
    truth = step_density()
    reading, noise = noisy(truth, 3)
    kept, width = denoise_density(reading, noise, noise_scale=0.0)  # no noise expected: nothing but flat areas smoothed
    np.testing.assert_allclose(kept, reading, atol=1e-6)
    assert not width.any()
    clean, _ = denoise_density(truth, noise)  # a noise-free step keeps its edge
    assert np.abs(clean - truth).max() < 0.02
