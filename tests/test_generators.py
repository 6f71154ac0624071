"""Reference point-pattern generators: counts, domain, determinism, and each one's spectrum.

Spectra are radial power spectra (:class:`synthesis.spectrum.RadialSpectrum`) at
n = 1024 averaged over three seeds; band means are over inclusive bin ranges.
The thresholds sit between what the generator produces and what the other
correlations (white noise in particular) would give.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from synthesis.errors import PatternshopError
from synthesis.generators import GENERATORS, generate
from synthesis.generators._torus import min_distance, r_max
from synthesis.spectrum import RadialSpectrum

N = 1024
SEEDS = (0, 1, 2)


@functools.cache
def points(name: str, n: int, seed: int) -> np.ndarray:
    """Cached ``generate(name, n, seed)``; copies are not needed as tests only read."""
    return generate(name, n, seed)


@functools.cache
def spectrum(name: str) -> np.ndarray:
    """(64,) radial spectrum of ``name`` at n = 1024, averaged over ``SEEDS``."""
    radial = RadialSpectrum(N)
    return np.mean([radial(points(name, N, seed)) for seed in SEEDS], axis=0)


def band(name: str, low: int, high: int) -> float:
    """Mean of the spectrum of ``name`` over bins low..high (inclusive)."""
    return float(spectrum(name)[low : high + 1].mean())


def test_registry_names() -> None:
    assert {"white", "blue", "green", "red", "step", "jitter"} <= set(GENERATORS)


@pytest.mark.parametrize("name", sorted(GENERATORS))
@pytest.mark.parametrize("n", [0, 1, 5, 256, 1000, N])
def test_exact_count_in_unit_square(name: str, n: int) -> None:
    result = points(name, n, 0)
    assert result.shape == (n, 2)
    assert result.dtype == np.float64
    assert np.all(result >= 0.0) and np.all(result < 1.0)


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_deterministic_per_seed(name: str) -> None:
    np.testing.assert_array_equal(generate(name, 256, 7), points(name, 256, 7))
    assert not np.array_equal(points(name, 256, 7), points(name, 256, 0))
    rng = np.random.default_rng(3)
    np.testing.assert_array_equal(GENERATORS[name](100, rng), generate(name, 100, 3))


def test_unknown_name_lists_valid_ones() -> None:
    with pytest.raises(PatternshopError, match="unknown pattern generator 'purple'.*white.*blue.*step") as info:
        generate("purple", 10)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("n", [-1, 2.5, "10"])
def test_bad_count(n: object) -> None:
    with pytest.raises(PatternshopError, match="point count"):
        generate("white", n)  # type: ignore[arg-type]


def test_white_is_flat_at_one() -> None:
    assert abs(band("white", 1, 63) - 1.0) < 0.15
    for low in range(1, 64, 9):  # flat: every band of 9 bins near 1
        assert 0.7 < band("white", low, low + 8) < 1.3, low


def test_blue_has_no_low_frequencies_and_a_peak() -> None:
    assert band("blue", 1, 12) < 0.2
    assert spectrum("blue")[25:46].max() > 1.4


def test_blue_minimum_distance() -> None:
    for seed in SEEDS:
        assert min_distance(points("blue", N, seed)) > 0.7 * r_max(N)


def test_green_is_clustered_at_mid_frequencies_only() -> None:
    assert band("green", 1, 6) < 0.85  # the clusters are spread as blue noise ...
    assert band("green", 1, 6) < 0.25 * band("red", 1, 6)
    assert band("green", 8, 24) > 1.6  # ... and each holds a few points


def test_red_has_energy_at_low_frequencies() -> None:
    assert band("red", 1, 8) > 4.0
    assert 0.8 < band("red", 30, 63) < 1.2


def test_step_is_zero_below_cutoff_and_one_above() -> None:
    assert band("step", 2, 13) < 0.25
    assert 0.8 < band("step", 22, 63) < 1.3
    assert spectrum("step")[18:].max() < 1.35  # a step, not a blue-noise peak


def test_step_refuses_unresolvable_counts() -> None:
    with pytest.raises(PatternshopError, match="limited to 4096 points"):
        generate("step", 4097)


def test_jitter_is_a_weak_blue_noise() -> None:
    assert band("jitter", 1, 6) < 0.2
    assert 0.4 < band("jitter", 12, 24) < 0.85  # rises gradually, unlike Poisson-disk or step noise
    assert 0.8 < band("jitter", 40, 63) < 1.2
    assert spectrum("jitter")[25:46].max() < 1.3  # no peak


def test_new_presets_are_registered() -> None:
    assert {"lattice", "perturbed", "lloyd", "matern"} <= set(GENERATORS)


def test_perfect_lattice_is_all_bragg_peaks() -> None:
    xy = points("lattice", N, 0)  # 1024 = 32 x 32: no vacancy
    side = 32
    residue = np.mod(xy * side, 1.0)
    np.testing.assert_allclose(residue - residue[0], 0.0, atol=1e-9)  # every point on one shifted grid
    assert spectrum("lattice")[1:31].max() < 1e-6  # nothing below the first peak at b = 32


def test_perturbed_lattice_is_a_very_regular_blue_noise() -> None:
    assert min_distance(points("perturbed", N, 0)) > 0.45 * r_max(N)
    assert spectrum("perturbed")[25:46].max() > 3 * spectrum("blue")[25:46].max()  # Bragg peaks survive the jitter
    assert band("perturbed", 1, 8) < band("blue", 1, 8)


def test_lloyd_is_a_stronger_blue_noise_than_poisson_disk() -> None:
    for seed in SEEDS:
        assert min_distance(points("lloyd", N, seed)) > 0.65 * r_max(N)
    assert spectrum("lloyd")[25:46].max() > spectrum("blue")[25:46].max()


def test_matern_clumps_are_tight_and_randomly_placed() -> None:
    assert band("matern", 1, 8) > 3.0  # clumps at random: low frequencies carry their count
    assert band("matern", 1, 8) < band("red", 1, 8)  # smaller clusters than red's 16


def test_generator_parameters_sweep_their_families() -> None:
    from synthesis.generators import blue, green, jitter, red

    rng = lambda: np.random.default_rng(4)  # noqa: E731 - same stream for every variant
    assert min_distance(blue.generate(N, rng(), relative_radius=0.4)) < 0.6 * r_max(N)
    assert min_distance(jitter.generate(N, rng(), strength=0.25)) > 0.7 / 32
    wide, tight = (red.generate(N, rng(), points_per_cluster=8, cluster_std=s) for s in (1.0, 0.2))
    assert min_distance(tight) < min_distance(wide)
    sizes = green.generate(N, rng(), points_per_cluster=3)
    assert sizes.shape == (N, 2)
