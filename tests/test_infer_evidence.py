"""infer's automatic scale and ink (issue 14), and infer with a model without l_scale: export/evidence.py and `patternshop infer`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from export.evidence import ScaleChoice, calibrate_density, choose_points_per_ink
from export.infer_config import DEFAULT_INFER
from patternshop_nn.onnx_export import export_onnx
from patternshop_nn.networks import DualBranchUNet
from synthesis.generators import generate
from synthesis.mapio import read_map
from synthesis.points import PointSet, write_points
from helpers import run_cli

DEFAULT = 50_000


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An untrained tiny model without an l_scale output (as older exports and models trained with l_scale=false)."""
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "tiny.onnx"
    export_onnx(DualBranchUNet(base_channels=4, max_channels=8, upsample="nearest"), path, {"points_per_ink": 8000})
    return path


@pytest.mark.parametrize(("process", "n", "raised"), [("white", 75_000, True), ("white", 50_000, False),
                                                      ("jitter", 50_000, False), ("white", 20_000, False)])
def test_scale_is_raised_only_for_patterns_denser_than_full_ink(process: str, n: int, raised: bool) -> None:
    choice = choose_points_per_ink(PointSet(generate(process, n, seed=1)), DEFAULT)
    assert choice.automatic
    if raised:  # the densest 1 % reads as full ink: a stationary pattern at 1.5 x full ink reads just below 1
        assert choice.local_density_quantile > DEFAULT_INFER.scale_threshold
        assert n < choice.points_per_ink < 1.15 * n
    else:
        assert choice.points_per_ink == DEFAULT and choice.local_density_quantile < DEFAULT_INFER.scale_threshold


def test_scale_of_an_empty_pattern_is_the_default() -> None:
    assert choose_points_per_ink(PointSet(np.zeros((0, 2))), DEFAULT).points_per_ink == DEFAULT


def test_infer_chooses_reports_and_keeps_an_override(tiny_model: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dense, sparse = tmp_path / "dense.txt", tmp_path / "sparse.txt"
    write_points(PointSet(generate("white", 75_000, seed=3)), dense)
    write_points(PointSet(generate("white", 30, seed=4)), sparse)
    report = tmp_path / "r.json"
    status, _, err = run_cli(["infer", str(dense), str(tmp_path / "d.tif"), "--model", str(tiny_model), "--report", str(report)], capsys)
    assert status == 0, err
    chosen = json.loads(report.read_text())
    assert chosen["automatic"] and 75_000 < chosen["points_per_ink"] < 1.15 * 75_000 and chosen["n"] == 75_000
    assert f"read at {ScaleChoice(chosen['points_per_ink'], True, chosen['local_density_quantile']).describe()}" in err
    assert "to synthesize to keep the point count" in err and "warning" not in err
    status, _, err = run_cli(["infer", str(dense), str(tmp_path / "g.tif"), "--model", str(tiny_model), "--points-per-ink", "60000",
                              "--report", str(report)], capsys)
    assert status == 0 and "60,000 points per ink (given)" in err and "saturated" in err
    assert json.loads(report.read_text())["points_per_ink"] == 60_000
    status, _, err = run_cli(["infer", str(sparse), str(tmp_path / "s.tif"), "--model", str(tiny_model), "--report", str(report)], capsys)
    assert status == 0 and "ink scaled by" in err and "to hold the 30 points" in err
    assert json.loads(report.read_text())["ink_calibration_factor"] > 0
    status, _, err = run_cli(["infer", str(sparse), str(tmp_path / "c.tif"), "--model", str(tiny_model), "--no-calibrate",
                              "--report", str(report)], capsys)
    assert status == 0 and "ink scaled" not in err and json.loads(report.read_text())["ink_calibration_factor"] is None


def test_convert_reads_each_file_at_its_own_scale(tiny_model: Path, tmp_path: Path) -> None:
    from export.convert import WRITTEN, convert_points
    from export.runtime import OnnxModel

    write_points(PointSet(generate("white", 75_000, seed=5)), tmp_path / "dense.txt")
    write_points(PointSet(generate("white", 5_000, seed=6)), tmp_path / "light.txt")
    sources = [tmp_path / "dense.txt", tmp_path / "light.txt"]
    dense, light = convert_points(sources, tmp_path / "auto", OnnxModel(tiny_model), workers=1)
    assert dense.status == light.status == WRITTEN
    assert len(dense.warnings) == 1 and "points per ink (automatic" in dense.warnings[0] and not light.warnings
    dense, _ = convert_points(sources, tmp_path / "given", OnnxModel(tiny_model), workers=1, points_per_ink=50_000)
    assert len(dense.warnings) == 1 and "saturated" in dense.warnings[0]


def test_infer_takes_an_empty_pattern(tiny_model: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """No points is a pattern too, and its map is white: the ink is calibrated to the points (none)."""
    source = tmp_path / "empty.txt"
    source.write_text("# domain: 1 0.5\n")
    status, _, err = run_cli(["infer", str(source), str(tmp_path / "e.tif"), "--model", str(tiny_model)], capsys)
    assert status == 0 and "from 0 points" in err
    lab = read_map(tmp_path / "e.tif").lab
    assert lab.shape == (128, 256, 3) and lab[..., 0].min() == pytest.approx(100.0, abs=0.01)


def test_calibrated_ink_holds_the_pattern_count() -> None:
    density = np.linspace(0.0, 0.5, 64 * 64).reshape(64, 64)
    calibrated, factor = calibrate_density(density, 0.6)  # uniform on [0, s/2] capped at 1 has mean 1 - 1/s: s = 2.5
    assert calibrated.mean() == pytest.approx(0.6, rel=1e-6) and calibrated.max() == 1.0  # water-filled under full ink
    assert factor == pytest.approx(2.5, rel=1e-3) and np.all(np.diff(calibrated.ravel()) >= 0)  # order kept
    light, factor = calibrate_density(density, 0.025)
    assert light == pytest.approx(density * 0.1, abs=1e-9) and factor == pytest.approx(0.1)
    white, factor = calibrate_density(density, 0.0)
    assert not white.any() and factor == 0.0
    blank, factor = calibrate_density(np.zeros((8, 8)), 0.3)  # nothing to scale: left as it is
    assert not blank.any() and factor == 1.0
    full, factor = calibrate_density(density, 0.9999)  # more than the ink can hold: full ink wherever there is ink
    assert np.array_equal(full, (density > 0).astype(float)) and factor == pytest.approx(1 / density[density > 0].min())


def bisected_calibration(density: np.ndarray, mean_density: float) -> tuple[np.ndarray, float]:
    """The plain reference for :func:`calibrate_density` (reachable means): bisection of the factor, 200 halvings."""
    low, high = 0.0, 1.0
    while np.minimum(high * density, 1.0).mean() < mean_density:
        low, high = high, high * 4.0
    for _ in range(200):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if np.minimum(middle * density, 1.0).mean() < mean_density else (low, middle)
    return np.minimum(high * density, 1.0), high


@pytest.mark.parametrize("seed", range(6))
def test_newton_calibration_equals_bisection(seed: int) -> None:
    rng = np.random.default_rng(seed)
    density = rng.random((171, 256)) ** rng.uniform(0.3, 4.0) * (rng.random((171, 256)) > 0.2 * (seed % 3))
    for mean_density in (0.003, 0.1, 0.4, 0.6, 0.75):
        if mean_density * density.size >= np.count_nonzero(density):
            continue
        calibrated, factor = calibrate_density(density, mean_density)
        reference, reference_factor = bisected_calibration(density, mean_density)
        assert factor == pytest.approx(reference_factor, rel=1e-9)
        np.testing.assert_allclose(calibrated, reference, rtol=1e-9, atol=1e-12)
        assert calibrated.mean() == pytest.approx(mean_density, rel=1e-10)


def test_model_without_l_scale_reads_once_per_symmetry_calibrates_and_does_not_smooth(tiny_model: Path) -> None:
    """A model without l_scale: one network pass per symmetry (light patterns too: no zoomed readings, no resamplings),
    the ink calibrated to the point count, L not smoothed (denoise or not); without calibration the network's L."""
    from export.runtime import OnnxModel, infer_map, network_map
    from synthesis.synthesize import point_count

    model = OnnxModel(tiny_model)
    assert not model.has_l_scale
    calls = []
    predict = model.predict_outputs
    model.predict_outputs = lambda rasters: calls.append(rasters.shape) or predict(rasters)
    for n in (200, 3_000):
        calls.clear()
        points = PointSet(generate("white", n, seed=7))
        inference = infer_map(points, model)
        assert len(calls) == DEFAULT_INFER.symmetries == inference.symmetries
        assert point_count(inference.lab_map, inference.scale.points_per_ink) == n
        assert inference.denoised_px == 0 and inference.l_scale is None
        report = inference.report()
        assert report["ink_calibration_factor"] > 0 and report["denoised_px"] == 0 and report["l_scale_mean"] is None
        assert not {"correlation_zooms", "sharpened_share", "thin_evidence_share"} & set(report)
        plain = infer_map(points, model, denoise=False)
        np.testing.assert_array_equal(plain.lab_map.lab, inference.lab_map.lab)
    raw = infer_map(PointSet(generate("white", 3_000, seed=7)), model, calibrate=False, symmetries=1)
    assert raw.calibration is None
    np.testing.assert_allclose(raw.lab_map.lab, network_map(raw.output, raw.lab_map.L.shape).lab, atol=1e-3)  # as it came


def test_symmetric_reading_is_equivariant(tiny_model: Path) -> None:
    """Averaged over the 8 symmetries, the reading of a flipped or transposed raster is the flipped or transposed
    reading (exactly, up to float rounding); one symmetry is the plain network run."""
    from export.runtime import OnnxModel, dihedral, predict_symmetric

    model = OnnxModel(tiny_model)
    raster = np.random.default_rng(8).random((128, 128), dtype=np.float32) * 0.3
    for code in range(8):
        np.testing.assert_array_equal(dihedral(dihedral(raster, code), code, inverse=True), raster)
    averaged = predict_symmetric(model, raster, 8)
    for code in (1, 2, 4, 7):
        turned = predict_symmetric(model, np.ascontiguousarray(dihedral(raster, code)), 8)
        np.testing.assert_allclose(turned, dihedral(averaged, code), atol=1e-5)
    np.testing.assert_allclose(predict_symmetric(model, raster, 1), model.predict(raster[None, None])[0], atol=1e-7)
    assert np.abs(predict_symmetric(model, raster, 4) - averaged).max() > 1e-4  # 4 and 8 differ on a generic network


def test_infer_notes_that_a_model_without_l_scale_is_not_smoothed(tiny_model: Path, tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    source, report = tmp_path / "poisson.txt", tmp_path / "r.json"
    write_points(PointSet(generate("white", 10_000, seed=5)), source)
    status, _, err = run_cli(["infer", str(source), str(tmp_path / "a.tif"), "--model", str(tiny_model), "--symmetries", "1",
                              "--report", str(report)], capsys)
    assert status == 0, err
    assert json.loads(report.read_text())["denoised_px"] == 0 and "L smoothed within" not in err
    assert [line for line in err.splitlines() if "has no l_scale output" in line] == [
        f"note: {tiny_model} has no l_scale output (predicted uncertainty of L): its L is not smoothed"]
    for removed in ("--no-fill", "--no-sharpen"):
        status, _, err = run_cli(["infer", str(source), str(tmp_path / "b.tif"), "--model", str(tiny_model), removed], capsys)
        assert status != 0 and "unrecognized arguments" in err
