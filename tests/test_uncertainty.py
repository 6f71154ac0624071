"""infer for models that predict their uncertainty of L (issue 28): export/uncertainty.py, export/infer_config.py and
the l_scale path of export/runtime.py."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from export.infer_config import DEFAULT_INFER, InferConfig
from export.uncertainty import smooth_by_uncertainty, smoothing_levels
from helpers import run_cli
from patternshop_nn.networks import DualBranchUNet
from patternshop_nn.onnx_export import export_onnx
from synthesis.generators import generate
from synthesis.points import PointSet, write_points

SIZE = 128
CONFIG = InferConfig(smoothing_tolerance=1.5)  # a calibrated Laplace scale: white noise changes by about b under a wide smoothing


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(untrained tiny model with an l_scale output, the same without it)."""
    folder = tmp_path_factory.mktemp("models")
    torch.manual_seed(0)
    generator = DualBranchUNet(base_channels=4, max_channels=8, upsample="nearest", l_scale=True)
    export_onnx(generator, folder / "scale.onnx", {"points_per_ink": 8000})
    export_onnx(generator, folder / "plain.onnx", {"points_per_ink": 8000}, l_scale=False)
    return folder / "scale.onnx", folder / "plain.onnx"


def noisy_step(noise: float = 0.03, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(noisy density (SIZE, SIZE): 0.2 left of the middle, 0.6 right, Laplace noise of scale ``noise``; the clean one)."""
    clean = np.where(np.arange(SIZE) < SIZE // 2, 0.2, 0.6)[None, :].repeat(SIZE, axis=0)
    return clean + np.random.default_rng(seed).laplace(0.0, noise, clean.shape), clean


def test_smoothing_is_wider_where_the_predicted_scale_is_larger() -> None:
    """The same noise everywhere; predicted small at the top, at its true size at the bottom: the bottom is smoothed
    wide and flat, the top keeps (most of) its grain."""
    flat = 0.4 + np.random.default_rng(1).laplace(0.0, 0.03, (SIZE, SIZE))
    scale = np.where(np.arange(SIZE)[:, None] < SIZE // 2, 0.003, 0.03) * np.ones((1, SIZE))
    smoothed, width = smooth_by_uncertainty(flat, scale, CONFIG)
    top, bottom = slice(8, SIZE // 2 - 24), slice(SIZE // 2 + 24, -8)
    assert width[bottom].mean() > 4 * width[top].mean() and width[bottom].mean() > 0.5 * max(smoothing_levels((SIZE, SIZE)))
    assert smoothed[bottom].std() < 0.2 * flat[bottom].std() and smoothed[top].std() > 0.5 * flat[top].std()


def test_smoothing_within_the_noise_keeps_an_edge_far_above_it() -> None:
    noisy, clean = noisy_step()
    smoothed, width = smooth_by_uncertainty(noisy, np.full(noisy.shape, 0.03), CONFIG)
    assert np.abs(smoothed - clean).mean() < 0.5 * np.abs(noisy - clean).mean()
    edge = slice(SIZE // 2 - 2, SIZE // 2 + 2)
    assert smoothed[:, SIZE // 2 + 1].mean() - smoothed[:, SIZE // 2 - 2].mean() > 0.3  # the 0.4 step stays a step
    assert width[:, edge].mean() < 0.5 * width[:, 8:24].mean()  # narrow at the edge, wide in the flat


def test_zero_scale_or_tolerance_smooths_nothing_but_flat_areas() -> None:
    noisy, _ = noisy_step()
    for scale, config in ((np.zeros(noisy.shape), CONFIG), (np.full(noisy.shape, 0.03), InferConfig(smoothing_tolerance=0.0))):
        smoothed, width = smooth_by_uncertainty(noisy, scale, config)
        np.testing.assert_allclose(smoothed, noisy, atol=1e-9)
        assert not width.any()
    flat = np.full((SIZE, SIZE), 0.3)
    np.testing.assert_allclose(smooth_by_uncertainty(flat, np.zeros_like(flat))[0], flat)


def test_config_refuses_bad_values() -> None:
    with pytest.raises(ValueError, match="symmetries"):
        InferConfig(symmetries=3)
    with pytest.raises(ValueError):
        InferConfig(smoothing_tolerance=-1.0)


def test_model_with_l_scale_reads_one_pass_per_symmetry_and_keeps_the_count(models: tuple[Path, Path]) -> None:
    from export.runtime import OnnxModel, infer_map
    from synthesis.synthesize import point_count

    model, plain = OnnxModel(models[0]), OnnxModel(models[1])
    assert model.has_l_scale and not plain.has_l_scale
    raster = np.zeros((1, 1, 64, 64), np.float32)
    assert model.predict_outputs(raster).shape == (1, 4, 64, 64) and model.predict(raster).shape == (1, 3, 64, 64)
    assert plain.predict_outputs(raster).shape == (1, 3, 64, 64)
    calls = []
    predict = model.predict_outputs
    model.predict_outputs = lambda rasters: calls.append(rasters.shape) or predict(rasters)
    points = PointSet(generate("white", 3_000, seed=7))  # light: still one pass per symmetry
    inference = infer_map(points, model)
    assert len(calls) == DEFAULT_INFER.symmetries == inference.symmetries
    assert point_count(inference.lab_map, inference.scale.points_per_ink) == len(points)
    assert inference.l_scale.shape == inference.lab_map.L.shape and inference.denoised_px > 0
    report = inference.report()
    assert report["l_scale_mean"] > 0
    empty = infer_map(PointSet(np.zeros((0, 2))), model)
    assert empty.lab_map.L.min() == pytest.approx(100.0, abs=1e-3) and empty.denoised_px == 0


def test_infer_with_a_changed_config_changes_the_result(models: tuple[Path, Path]) -> None:
    """InferConfig is what infer reads: each changed field changes the map (and the default is what it runs)."""
    from patternshop import api

    model = api.load_model(models[0])
    points = PointSet(generate("white", 8_000, seed=3))
    default = api.infer(points, model=model).lab_map.L
    np.testing.assert_array_equal(api.infer(points, model=model, config=InferConfig()).lab_map.L, default)
    for change in ({"smoothing_tolerance": 0.0}, {"border_px": 0}, {"symmetries": 1 if DEFAULT_INFER.symmetries > 1 else 2},
                   {"smoothing_max_fraction": 1.0 / 64}):
        changed = api.infer(points, model=model, config=dataclasses.replace(DEFAULT_INFER, **change)).lab_map.L
        assert np.abs(changed - default).max() > 1e-3, change


def test_two_symmetries_average_a_flip(models: tuple[Path, Path]) -> None:
    from export.runtime import OnnxModel, dihedral, predict_symmetric

    model = OnnxModel(models[0])
    raster = np.random.default_rng(8).random((128, 128), dtype=np.float32) * 0.3
    averaged = predict_symmetric(model, raster, 2)
    assert averaged.shape == (4, 128, 128)
    flipped = predict_symmetric(model, np.ascontiguousarray(dihedral(raster, 1)), 2)
    np.testing.assert_allclose(flipped, dihedral(averaged, 1), atol=1e-5)


def test_infer_command_with_an_l_scale_model_chooses_the_scale_once(models: tuple[Path, Path], tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str],
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    import export.evidence

    source, report = tmp_path / "poisson.txt", tmp_path / "r.json"
    write_points(PointSet(generate("white", 10_000, seed=5)), source)  # no header: the scale is chosen from the points
    chosen = []
    choose = export.evidence.choose_points_per_ink
    monkeypatch.setattr(export.evidence, "choose_points_per_ink", lambda *a: chosen.append(1) or choose(*a))
    status, _, err = run_cli(["infer", str(source), str(tmp_path / "a.tif"), "--model", str(models[0]), "--report", str(report)],
                             capsys)
    assert status == 0, err
    assert len(chosen) == 1  # the command's scale is the one infer reads at, not chosen again
    written = json.loads(report.read_text())
    assert written["symmetries"] == DEFAULT_INFER.symmetries and written["l_scale_mean"] > 0 and written["denoised_px"] > 0
    assert "L smoothed within the network's predicted uncertainty" in err and "has no l_scale output" not in err


def test_scale_choice_reads_the_config() -> None:
    from patternshop import api

    points = PointSet(generate("white", 75_000, seed=1))  # 1.5 x full ink at the default 50,000 points per ink
    chosen = api.infer_scale(points)
    assert chosen.points_per_ink > 75_000
    assert api.infer_scale(points, config=InferConfig(scale_threshold=2.0)).points_per_ink == 50_000
    median = api.infer_scale(points, config=InferConfig(scale_quantile=0.5))
    assert 50_000 < median.points_per_ink < chosen.points_per_ink and "50th-percentile" in median.describe()


def test_smoothing_with_matrix_gaussians_is_the_plain_one(monkeypatch: pytest.MonkeyPatch) -> None:
    """smooth_by_uncertainty with export.gaussian's float32 products against the same ladder with scipy's filter
    everywhere: within float32 rounding (the widths fade continuously with the change, so they move as little)."""
    from scipy.ndimage import gaussian_filter

    import export.uncertainty as uncertainty

    noisy, _ = noisy_step(seed=5)
    density = np.clip(np.pad(noisy, ((0, 0), (0, 2 * SIZE)), mode="reflect"), 0.0, 1.0)  # 128 x 384: wide kernels
    scale = np.full(density.shape, 0.03) * np.linspace(0.2, 2.0, density.shape[1])
    fast = smooth_by_uncertainty(density, scale, CONFIG)
    monkeypatch.setattr(uncertainty, "gaussian", lambda image, sigma, truncate=4.0: gaussian_filter(image, sigma, truncate=truncate))
    plain = smooth_by_uncertainty(density, scale, CONFIG)
    assert max(smoothing_levels(density.shape, CONFIG)) >= 16  # wide levels and windows included
    np.testing.assert_allclose(fast[0], plain[0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(fast[1], plain[1], rtol=0, atol=1e-4)
    assert fast[1].max() > 8  # some pixels climb the wide levels: the comparison is not vacuous
