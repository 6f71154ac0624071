"""The frozen test set (patternshop_nn/testset.py): its builder deterministic, its stipplers never trained on, its scorer.

Only a tiny stand-in picture is built and scored here (never the frozen photos: they are scored once per shipped model).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from data_gen.pairs import PairSettings, other_methods_setting
from data_gen.provenance import compose_config
from data_gen.stipplers import FROZEN_METHODS, LABELS, METHODS
from export.runtime import DEFAULT_MODEL
from patternshop_nn import testset
from patternshop_nn.baselines import KDE_BANDWIDTHS
from synthesis.errors import PatternshopError
from synthesis.points import read_points


def stand_in() -> np.ndarray:
    rows, cols = np.mgrid[0:36, 0:48]
    return np.stack([(cols * 5) % 256, (rows * 7) % 256, ((rows + cols) * 3) % 256], -1).astype(np.uint8)


@pytest.fixture(scope="module")
def tiny_set(tmp_path_factory):
    """A set of the stand-in picture, 300 points by each test method (synthesis: 8 iterations)."""
    folder = tmp_path_factory.mktemp("tiny_set")
    testset.build_test_set(folder, {"tiny": stand_in()}, n=300, synthesis_iterations=8)
    return folder


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


def test_score_writes_the_report_of_a_tiny_set(tiny_set, tmp_path, capsys):
    out = tmp_path / "result"
    assert testset.main(["score", str(tiny_set), "--model", str(DEFAULT_MODEL), "--out", str(out)]) == 0
    results = json.loads((out / "score.json").read_text())
    assert [(r["picture"], r["method"]) for r in results["cases"]] == [("tiny", m) for m in testset.TEST_METHODS]
    assert results["model_sha256"] == testset.sha256_file(DEFAULT_MODEL) and not results["frozen"]
    assert results["manifest_sha256"] == testset.sha256_file(tiny_set / "manifest.json")
    report = (out / "score.md").read_text()
    assert "Not the frozen test set" in report and results["model_sha256"] in report and results["manifest_sha256"] in report
    for row in results["cases"]:
        assert row["map_shape"] == [192, 256]  # infer's default 256 px on the long side of the 4:3 domain
        assert any("from the file's header" in line for line in row["infer_messages"])
        assert row["oracle_ssim_bandwidth_px"] in KDE_BANDWIDTHS and 0 < row["ssim"] <= 1
        assert row["won_oracle"] == (row["ssim"] > row["oracle_ssim"] and row["mae"] < row["oracle_mae"])
        assert f"| tiny | {row['method']} | {row['n']} | {row['ssim']:.4f} | {row['mae']:.3f} |" in report
        assert (out / "maps" / f"tiny.{row['method']}.tif").is_file()
    assert [t["measured"] for t in results["targets"]][::2] == [
        f"{sum(r['won_oracle'] for r in results['cases'])} of 4", f"{sum(r['won_one_spacing'] for r in results['cases'])} of 4"]
    assert (out / "tiny.sheet.png").stat().st_size > 0
    assert json.loads(capsys.readouterr().out)["cases"] == 4


def test_a_tampered_set_is_refused(tiny_set, tmp_path, capsys):
    folder = tmp_path / "set"
    shutil.copytree(tiny_set, folder)
    with (folder / "tiny.sierra_serpentine.txt").open("a") as handle:
        handle.write("0.5 0.5\n")
    out = tmp_path / "result"
    assert testset.main(["score", str(folder), "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "tiny.sierra_serpentine.txt" in error and "refusing to score" in error
    assert not out.exists()


def test_won_needs_a_higher_ssim_and_a_lower_mae():
    assert testset.won(0.80, 2.0, 0.79, 2.1)
    assert not testset.won(0.80, 2.2, 0.79, 2.1)  # better SSIM, worse MAE
    assert not testset.won(0.78, 2.0, 0.79, 2.1)  # better MAE, worse SSIM
    assert not testset.won(0.79, 2.1, 0.79, 2.1)  # a tie is lost
    rows = [{"won_oracle": k != 7, "won_one_spacing": True, "ssim_loss_to_oracle": 0.0} for k in range(8)]
    assert [t["met"] for t in testset.score_targets(rows)] == [True, True, True]  # 7 of 8 is enough
    rows[6] = {"won_oracle": False, "won_one_spacing": False, "ssim_loss_to_oracle": 0.031}
    assert [t["measured"] for t in testset.score_targets(rows)] == ["6 of 8", 0.031, "7 of 8"]
    assert [t["met"] for t in testset.score_targets(rows)] == [False, False, False]
