"""infer's automatic scale and correlation evidence (issue 14): export/evidence.py and `patternshop infer`."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from export.evidence import (EVIDENCE_RADIUS_PX, INKED_DENSITY, MAX_ZOOM, WORK_DENSITY, ZOOM_NEIGHBOURHOOD_PX, ScaleChoice, blend_zoomed,
                             calibrate_density, choose_points_per_ink, correlation_zoom, fill_thin_correlation, local_evidence,
                             summarise, zoom_levels)
from export.infer_config import DEFAULT_INFER
from patternshop_nn.onnx_export import export_onnx
from patternshop_nn.networks import DualBranchUNet
from synthesis.generators import generate
from synthesis.labmap import LabMap
from synthesis.mapio import read_map
from synthesis.points import PointSet, write_points
from helpers import run_cli

DEFAULT = 50_000


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
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


def test_evidence_counts_points_in_the_raster_window() -> None:
    """20,000 Poisson points read at 640 raster px per unit: pi 12^2 px x 20,000 / 640^2 points in the window."""
    evidence = local_evidence(PointSet(generate("white", 20_000, seed=2)), (256, 256), 640.0)
    expected = math.pi * EVIDENCE_RADIUS_PX**2 * 20_000 / 640**2
    assert evidence[32:-32, 32:-32].mean() == pytest.approx(expected, rel=0.05)
    assert summarise(evidence, False, False).thin_share == 0.0


def test_uninked_pixels_are_filled_even_where_points_are_near() -> None:
    """Every pixel has evidence (its window reaches the points), but the right half holds no ink (L 100): its a, b,
    echoing the points next to it, is replaced by the inked half's. A map with no inked pixel falls back to the evidence."""
    lab = np.zeros((64, 64, 3), np.float32)
    lab[:, :32] = (50.0, 0.0, 0.0)
    lab[:, 32:] = (100.0, 60.0, 25.0)
    filled, source = fill_thin_correlation(LabMap(lab), np.full((64, 64), 50.0))
    assert source
    np.testing.assert_allclose(filled.ab, 0.0, atol=1e-3)
    np.testing.assert_array_equal(filled.L, LabMap(lab).L)
    light = lab.copy()
    light[:, :32, 0] = 100.0 * (1.0 - 0.5 * INKED_DENSITY)  # inked below INKED_DENSITY everywhere: evidence alone decides
    evidence = np.zeros((64, 64))
    evidence[:, :32] = 50.0
    filled, source = fill_thin_correlation(LabMap(light), evidence)
    assert source
    np.testing.assert_allclose(filled.ab, 0.0, atol=1e-3)


def test_thin_correlation_is_filled_from_the_surroundings() -> None:
    """Left half well observed with (-2, -128), right half empty with another colour: the right half takes the left's."""
    lab = np.zeros((64, 64, 3), np.float32)
    lab[..., 0] = np.linspace(20, 99, 64)[None, :]
    lab[:, :32, 1:] = (-2.0, -128.0)
    lab[:, 32:, 1:] = (40.0, 40.0)
    evidence = np.zeros((64, 64))
    evidence[:, :32] = 50.0
    filled, source = fill_thin_correlation(LabMap(lab), evidence)
    assert source
    np.testing.assert_array_equal(filled.L, LabMap(lab).L)
    np.testing.assert_allclose(filled.ab, np.broadcast_to([-2.0, -128.0], (64, 64, 2)), atol=1e-3)
    unchanged, source = fill_thin_correlation(LabMap(lab), np.zeros((64, 64)))
    assert not source and np.array_equal(unchanged.lab, LabMap(lab).lab)
    summary = summarise(evidence + np.where(np.arange(64) >= 48, 0.0, 3.0)[None, :] * (np.arange(64) >= 32), True, True)
    assert summary.thin_share == pytest.approx(0.25) and summary.empty_share == pytest.approx(0.25)


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
    assert status == 0 and "of the map has too few points to show correlation; its a,b were filled" in err
    assert "ink scaled by" in err and "to hold the 30 points" in err and "read at fewer points per ink (2x, 4x, 8x, 16x, 32x, 64x)" in err
    sparse_report = json.loads(report.read_text())
    assert sparse_report["thin_evidence_share"] > 0.5 and sparse_report["correlation_zooms"] == [1, 2, 4, 8, 16, 32, 64]
    status, _, err = run_cli(["infer", str(sparse), str(tmp_path / "c.tif"), "--model", str(tiny_model), "--no-calibrate",
                              "--report", str(report)], capsys)
    assert status == 0 and "ink scaled" not in err and json.loads(report.read_text())["ink_calibration_factor"] is None
    status, _, err = run_cli(["infer", str(sparse), str(tmp_path / "n.tif"), "--model", str(tiny_model), "--no-fill"], capsys)
    assert status == 0 and "left as the network gave them" in err


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


def test_correlation_zoom_reads_light_areas_at_the_working_density() -> None:
    blocks = np.repeat([1.0, WORK_DENSITY, WORK_DENSITY / 4, WORK_DENSITY / 10, 0.0], 10)[None]  # (1, 50): 10-px blocks
    zoom_of_blocks = correlation_zoom(blocks)
    assert zoom_of_blocks[0, 5::10] == pytest.approx([1.0, 1.0, 4.0, 10.0, MAX_ZOOM])
    # a light pixel is zoomed as the densest pixel within ZOOM_NEIGHBOURHOOD_PX: next to a darker block, that block's zoom
    assert zoom_of_blocks[0, 20 + ZOOM_NEIGHBOURHOOD_PX - 1] == 1.0 and zoom_of_blocks[0, 20 + ZOOM_NEIGHBOURHOOD_PX] == pytest.approx(4.0)
    zoom = zoom_of_blocks[:, 5::10]
    levels = (1, 2, 4, 8, 16, 32, 64)
    assert zoom_levels(zoom) == levels and zoom_levels(zoom[:, :3]) == (1, 2, 4) and zoom_levels(zoom[:, :2]) == (1,)
    readings = [np.full((1, 5, 2), 0.0 if level == 1 else float(level)) for level in levels]
    blended = blend_zoomed(zoom, levels, readings)
    # exact at the levels, linear in log zoom between the two around it: zoom 10 lies at log2(10) - 3 = 0.32 of the way from 8 to 16
    assert blended[0, :, 0] == pytest.approx([0.0, 0.0, 4.0, 8.0 + 8.0 * (math.log2(10) - 3), 64.0])


def test_infer_keeps_the_point_count_and_reads_light_patterns_zoomed(tiny_model: Path) -> None:
    from export.runtime import OnnxModel, infer_map
    from synthesis.synthesize import point_count

    model = OnnxModel(tiny_model)
    for n in (200, 3_000):
        inference = infer_map(PointSet(generate("white", n, seed=7)), model)
        assert point_count(inference.lab_map, inference.scale.points_per_ink) == n
        assert inference.zooms[-1] > 1 and inference.zoomed_share > 0.9
        report = inference.report()
        assert report["correlation_zooms"] == list(inference.zooms) and report["ink_calibration_factor"] > 0
    raw = infer_map(PointSet(generate("white", 3_000, seed=7)), model, fill_thin=False, calibrate=False)
    assert raw.zooms == (1,) and raw.calibration is None


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


def test_infer_sharpens_l_of_regular_patterns_only(tiny_model: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from scipy.stats import qmc

    regular, poisson = tmp_path / "regular.txt", tmp_path / "poisson.txt"
    write_points(PointSet(qmc.PoissonDisk(2, radius=0.006, seed=1).fill_space()), regular)
    write_points(PointSet(generate("white", 15_000, seed=2)), poisson)
    report = tmp_path / "r.json"
    status, _, err = run_cli(["infer", str(regular), str(tmp_path / "a.tif"), "--model", str(tiny_model), "--report", str(report)], capsys)
    assert status == 0, err
    assert json.loads(report.read_text())["sharpened_share"] > 0.8 and "sharpened from its regular points" in err
    status, _, err = run_cli(["infer", str(poisson), str(tmp_path / "b.tif"), "--model", str(tiny_model), "--report", str(report)], capsys)
    assert status == 0 and json.loads(report.read_text())["sharpened_share"] < 0.1
    status, _, err = run_cli(["infer", str(regular), str(tmp_path / "c.tif"), "--model", str(tiny_model), "--no-sharpen",
                              "--report", str(report)], capsys)
    assert status == 0 and json.loads(report.read_text())["sharpened_share"] == 0 and "sharpened" not in err


def test_sharpening_changes_l_only_and_keeps_the_point_count(tiny_model: Path) -> None:
    from scipy.stats import qmc

    from export.runtime import OnnxModel, infer_map
    from synthesis.synthesize import point_count

    model = OnnxModel(tiny_model)
    points = PointSet(qmc.PoissonDisk(2, radius=0.008, seed=3).fill_space())
    sharp, plain = infer_map(points, model, symmetries=1), infer_map(points, model, symmetries=1, sharpen=False)
    assert sharp.sharpened_share > 0.8 and plain.sharpened_share == 0
    np.testing.assert_array_equal(sharp.lab_map.ab, plain.lab_map.ab)
    assert not np.array_equal(sharp.lab_map.L, plain.lab_map.L)
    assert point_count(sharp.lab_map, sharp.scale.points_per_ink) == len(points)


def test_denoising_changes_l_only_deterministically_and_keeps_the_point_count(tiny_model: Path) -> None:
    from export.runtime import OnnxModel, infer_map
    from synthesis.synthesize import point_count

    model = OnnxModel(tiny_model)
    points = PointSet(generate("white", 12_000, seed=4))
    denoised, again = infer_map(points, model, symmetries=1), infer_map(points, model, symmetries=1)
    plain = infer_map(points, model, symmetries=1, denoise=False)
    assert denoised.denoised_px > 0 and plain.denoised_px == 0
    np.testing.assert_array_equal(denoised.lab_map.L, again.lab_map.L)  # the resampling's seed is fixed
    np.testing.assert_array_equal(denoised.lab_map.ab, plain.lab_map.ab)
    assert not np.array_equal(denoised.lab_map.L, plain.lab_map.L)
    assert point_count(denoised.lab_map, denoised.scale.points_per_ink) == len(points)


def test_infer_reports_denoising_and_no_denoise_turns_it_off(tiny_model: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    source, report = tmp_path / "poisson.txt", tmp_path / "r.json"
    write_points(PointSet(generate("white", 10_000, seed=5)), source)
    status, _, err = run_cli(["infer", str(source), str(tmp_path / "a.tif"), "--model", str(tiny_model), "--symmetries", "1",
                              "--report", str(report)], capsys)
    assert status == 0, err
    assert json.loads(report.read_text())["denoised_px"] > 0 and "L smoothed where its detail is noise" in err
    status, _, err = run_cli(["infer", str(source), str(tmp_path / "b.tif"), "--model", str(tiny_model), "--symmetries", "1",
                              "--no-denoise", "--report", str(report)], capsys)
    assert status == 0 and json.loads(report.read_text())["denoised_px"] == 0 and "smoothed" not in err


def test_bootstrap_noise_matches_the_shipped_networks_noise_on_poisson_points() -> None:
    """The noise sample denoising compares with: two readings of Poisson resamplings of the map. On a
    stationary Poisson pattern the network's own reading is all noise, so its fine detail must have the
    sample's energy (measured 0.86-0.99 at 8 symmetries, density 0.2 and 0.5)."""
    from scipy.ndimage import gaussian_filter

    from export.runtime import DEFAULT_MODEL, OnnxModel, bootstrap_noise, infer_map

    model = OnnxModel(DEFAULT_MODEL)
    points = PointSet(generate("white", 20_000, seed=6))
    reading = infer_map(points, model, scale=ScaleChoice(DEFAULT, False), symmetries=1, sharpen=False, denoise=False)
    density = reading.lab_map.density().astype(np.float64)
    noise = bootstrap_noise(points, model, density, DEFAULT, symmetries=1)
    inner = (slice(24, -24), slice(24, -24))
    for level in (2.0, 4.0):
        detail = lambda x: (x - gaussian_filter(x, level))[inner]
        assert 0.7 < np.mean(detail(density) ** 2) / np.mean(detail(noise) ** 2) < 1.3


def test_denoising_flattens_the_shipped_networks_reading_of_a_uniform_poisson_pattern() -> None:
    from export.runtime import DEFAULT_MODEL, OnnxModel, infer_map

    model = OnnxModel(DEFAULT_MODEL)
    points = PointSet(generate("white", 20_000, seed=7))
    spread = lambda inference: float(np.subtract(*np.percentile(inference.lab_map.L, [95, 5])))
    denoised = infer_map(points, model, scale=ScaleChoice(DEFAULT, False), symmetries=1)
    plain = infer_map(points, model, scale=ScaleChoice(DEFAULT, False), symmetries=1, denoise=False)
    assert spread(denoised) < 0.5 * spread(plain)
