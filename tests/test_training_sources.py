"""Issue 28's training data: the other stipplers (data_gen/stipplers.py) and the texture maps (data_gen/makers/textures.py)."""

from __future__ import annotations

import numpy as np
import pytest

from data_gen.makers import build_maker
from data_gen.makers.textures import MIN_MEAN, TEXTURES, texture_picture
from data_gen.pairs import PairSettings, generate
from data_gen.provenance import compose_config
from data_gen.shards import load_pairs, target_to_map
from data_gen.stipplers import DEFAULT_METHODS, LABELS, METHODS, bayer_matrix
from synthesis.synthesize import point_count

NEW = ("floyd_steinberg", "jarvis", "floyd_steinberg_jitter", "bayer", "lloyd_few", "lloyd_many")


def gradient(shape=(40, 60)) -> np.ndarray:
    return np.tile(np.linspace(0.1, 0.9, shape[1]), (shape[0], 1))


@pytest.mark.parametrize("method", NEW)
def test_new_stipplers_make_about_n_points_deterministically(method):
    density, domain, n = gradient(), (1.0, 40 / 60), 800
    xy = METHODS[method](density, n, domain, np.random.default_rng(3))
    assert abs(len(xy) - n) <= 0.04 * n
    assert np.all((xy >= 0) & (xy <= domain))
    np.testing.assert_array_equal(xy, METHODS[method](density, n, domain, np.random.default_rng(3)))
    right, left = np.sum(xy[:, 0] > 0.5), np.sum(xy[:, 0] < 0.5)
    assert right > 1.5 * left  # the density's gradient: about 2.3 times as many on the right


def test_every_training_method_has_a_label_and_the_defaults_are_unchanged():
    assert set(METHODS) == set(LABELS)
    assert DEFAULT_METHODS == ("random", "lloyd", "poisson_disk", "jitter", "clusters")
    assert all(isinstance(LABELS[name], str) for name in DEFAULT_METHODS)
    assert all(len(LABELS[name]) == 2 for name in NEW)  # measured a, b
    assert sorted(bayer_matrix(2).ravel() * 16 - 0.5) == list(range(16))


@pytest.mark.parametrize("kind", sorted(TEXTURES))
def test_textures_are_deterministic_and_in_range(kind):
    first = TEXTURES[kind](48, np.random.default_rng(5))
    assert first.shape == (48, 48) and first.dtype == np.float32
    assert 0.0 <= first.min() and first.max() <= 1.0 and first.std() > 0.02
    np.testing.assert_array_equal(first, TEXTURES[kind](48, np.random.default_rng(5)))
    assert not np.array_equal(first, TEXTURES[kind](48, np.random.default_rng(6)))
    _, toned = texture_picture(48, np.random.default_rng(5), {kind: 1.0})
    assert toned.mean() >= MIN_MEAN - 1e-6 and 0.0 <= toned.min() and toned.max() <= 1.0


def test_textures_dataset_is_deterministic():
    maker = build_maker({"name": "textures", "items": 4}, 32)
    first = maker.make(0, np.random.default_rng([0, 0])).lab
    np.testing.assert_array_equal(first, maker.make(0, np.random.default_rng([0, 0])).lab)
    assert len(maker) == 4 and first.shape == (32, 32, 3)


def test_new_options_leave_the_default_pairs_and_key_unchanged():
    def key(*overrides):
        return PairSettings.from_config(compose_config("pairs", ["map_size=32", *overrides])).key()

    assert key() == key("textures.kinds={text: 1.0}") != key("textures.share=0.5")
    shipped = ["other_methods.share=0.35"]
    weights_only = "other_methods.methods={random: 1.0, lloyd: 1.0, poisson_disk: 1.0, jitter: 1.0, clusters: 1.0}"
    assert key(*shipped) == key(*shipped, weights_only)  # the zero-weight new methods are not part of the key
    assert key(*shipped) != key(*shipped, "other_methods.methods.bayer=1.0")


def test_tiny_pairs_run_with_textures_and_new_stipplers(tmp_path):
    folder = tmp_path / "pairs"
    methods = [f"other_methods.methods.{name}={float(name in ('jarvis', 'bayer', 'lloyd_few', 'floyd_steinberg_jitter'))}"
               for name in METHODS]
    generate(compose_config("pairs", [f"out_dir={folder}", "num_items=4", "workers=1", "map_size=48", "raster_size=48",
                                      "synthesis.points_per_ink=1500", "other_methods.share=1.0", *methods,
                                      "textures.share=1.0"]))
    pairs = load_pairs(folder)
    assert len(pairs.meta) == 4
    for k, meta in enumerate(pairs.meta):
        a, b = LABELS[meta["method"]]
        target = pairs.target[k]
        assert np.all(target[..., 1] == round(a) + 128) and np.all(target[..., 2] == round(b) + 128)
        assert meta["method"] in ("jarvis", "bayer", "lloyd_few", "floyd_steinberg_jitter")
        wanted = point_count(target_to_map(target), 1500)
        assert abs(len(pairs.points_of(k)) - wanted) <= 0.1 * wanted, (meta, wanted)
