"""The frozen test set's builder (patternshop_nn/testset.py): deterministic, and its stipplers never trained on.

Only a tiny stand-in picture is built here (never the frozen photos: they are scored once per shipped model).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from data_gen.pairs import PairSettings, other_methods_setting
from data_gen.provenance import compose_config
from data_gen.stipplers import FROZEN_METHODS, LABELS, METHODS
from patternshop_nn import testset
from synthesis.errors import PatternshopError
from synthesis.points import read_points


def stand_in() -> np.ndarray:
    rows, cols = np.mgrid[0:36, 0:48]
    return np.stack([(cols * 5) % 256, (rows * 7) % 256, ((rows + cols) * 3) % 256], -1).astype(np.uint8)


def test_build_is_deterministic_on_a_tiny_picture(tmp_path):
    first = testset.build_test_set(tmp_path / "a", {"tiny": stand_in()}, n=300, synthesis_iterations=8)
    second = testset.build_test_set(tmp_path / "b", {"tiny": stand_in()}, n=300, synthesis_iterations=8)
    assert first == second
    assert json.loads((tmp_path / "a" / "manifest.json").read_text()) == first
    (picture,) = first["pictures"]
    assert [s["method"] for s in picture["stipplings"]] == list(testset.TEST_METHODS)
    for stippling in picture["stipplings"]:
        path = tmp_path / "a" / stippling["file"]
        assert testset.sha256_file(path) == stippling["sha256"] and abs(stippling["n"] - 300) <= 15
        points = read_points(path)
        assert points.domain == pytest.approx((1.0, 0.75)) and len(points.xy) == stippling["n"]
        assert points.points_per_ink == pytest.approx(stippling["points_per_ink"], rel=1e-3)
    truth = np.load(tmp_path / "a" / picture["truth"])
    assert truth.shape == (36, 48) and truth.dtype == np.float32 and 0 <= truth.min() <= truth.max() <= 1


def test_frozen_methods_are_the_test_sets_and_never_training_methods():
    assert set(testset.TEST_METHODS) - set(FROZEN_METHODS) == {f"synthesis_seed{s}" for s in testset.SYNTHESIS_SEEDS}
    assert not set(FROZEN_METHODS) & (set(METHODS) | set(LABELS))
    assert testset.TEST_PICTURES == ("china.jpg", "flower.jpg")
    for name in FROZEN_METHODS:
        with pytest.raises(ValueError, match="frozen test set"):
            other_methods_setting({"share": 0.5, "methods": {"random": 1.0, name: 1.0}})
        with pytest.raises(PatternshopError, match="frozen test set"):
            PairSettings.from_config(compose_config("pairs", ["map_size=32", "other_methods.share=0.5",
                                                              f"+other_methods.methods.{name}=1"]))
    with pytest.raises(ValueError, match="unknown test-set method"):
        testset.stipple("lloyd", np.full((8, 8), 0.5), (1.0, 1.0), 10)
