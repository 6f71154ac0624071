"""ONNX export and ONNX Runtime inference: parity with torch, dynamic batch, metadata, `patternshop infer` and `export`."""

from __future__ import annotations

from pathlib import Path

import lightning
import numpy as np
import onnx
import pytest
from helpers import run_cli
import torch

from data_gen.provenance import file_sha256
from patternshop_nn.onnx_export import OPSET, export_onnx, max_abs_difference
from export.infer_config import DEFAULT_INFER
from export.runtime import OnnxModel, check_palette, mirrored, pattern_raster, points_to_map
from patternshop_nn.module import Pix2PixModule
from synthesis.errors import PatternshopError, PatternshopWarning
from synthesis.mapio import read_map
from synthesis.palette import DEFAULT_PALETTE
from synthesis.points import PointSet, write_points
from synthesis.raster import point_raster

CARD = {"name": "tiny", "dataset": "test", "points_per_ink": 8000, "notes": {"steps": 0}}


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """Run the CLI in-process; returns (exit status, stderr)."""
    status, _, err = run_cli(argv, capsys)
    return status, err


@pytest.fixture(scope="module")
def tiny_module() -> Pix2PixModule:
    """An untrained small generator (4 to 8 channels) with non-trivial batch-norm statistics."""
    torch.manual_seed(0)
    module = Pix2PixModule(base_channels=4, max_channels=8)
    for layer in module.generator.modules():
        if isinstance(layer, torch.nn.BatchNorm2d):
            layer.running_mean.uniform_(-0.1, 0.1)
            layer.running_var.uniform_(0.5, 1.5)
    return module


@pytest.fixture(scope="module")
def tiny_onnx(tiny_module: Pix2PixModule, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("model") / "tiny.onnx"
    export_onnx(tiny_module, path, CARD)
    return path


def test_resize_convolution_model_is_exported_fused_and_equal(tmp_path: Path) -> None:
    """A nearest-up-sampling generator goes out with its up-sampling fused (no Resize node left) and computes the same maps."""
    import onnx

    torch.manual_seed(3)
    module = Pix2PixModule(base_channels=4, max_channels=8, upsample="nearest")
    path = tmp_path / "nearest.onnx"
    export_onnx(module, path, CARD)
    ops = {node.op_type for node in onnx.load(str(path)).graph.node}
    assert "Resize" not in ops and "DepthToSpace" in ops
    rng = np.random.default_rng(4)
    assert max_abs_difference(module, path, rng.random((2, 1, 256, 256), dtype=np.float32)) <= 1e-5
    assert max_abs_difference(module, path, rng.random((1, 1, 320, 320), dtype=np.float32)) <= 1e-5


def uniform_points(n: int, domain: tuple[float, float] = (1.0, 1.0), seed: int = 0) -> PointSet:
    return PointSet(np.random.default_rng(seed).random((n, 2)) * domain, domain)


def test_parity_on_random_and_point_rasters(tiny_module, tiny_onnx):
    rng = np.random.default_rng(1)
    assert max_abs_difference(tiny_module, tiny_onnx, rng.random((2, 1, 256, 256), dtype=np.float32)) <= 1e-4
    rasters = np.stack([point_raster(uniform_points(2000, seed=2).xy), point_raster(uniform_points(800, (1.0, 0.6)).xy)])
    assert rasters.max() > 0
    assert max_abs_difference(tiny_module, tiny_onnx, rasters[:, None]) <= 1e-4


def test_export_leaves_the_module_in_its_mode(tiny_module, tmp_path):
    tiny_module.train()
    export_onnx(tiny_module, tmp_path / "m.onnx")
    assert tiny_module.generator.training


def test_dynamic_batch_and_size(tiny_onnx):
    graph_input = onnx.load(str(tiny_onnx)).graph.input[0]
    assert [d.dim_param or d.dim_value for d in graph_input.type.tensor_type.shape.dim] == ["batch", 1, "height", "width"]
    model = OnnxModel(tiny_onnx)
    rasters = np.random.default_rng(3).random((3, 1, 256, 256), dtype=np.float32)
    batch = model.predict(rasters)
    single = model.predict(rasters[1:2])
    assert batch.shape == (3, 3, 256, 256) and single.shape == (1, 3, 256, 256)
    assert batch.dtype == np.float32 and 0 <= batch.min() and batch.max() <= 1
    np.testing.assert_allclose(single[0], batch[1], atol=1e-5)
    assert model.predict(rasters[:, :, :128, :192]).shape == (3, 3, 128, 192)
    with pytest.raises(ValueError, match="shape"):
        model.predict(rasters[:, :, :100, :128])


def test_metadata_round_trip(tiny_onnx):
    model = onnx.load(str(tiny_onnx))
    assert [o.version for o in model.opset_import if o.domain in ("", "ai.onnx")] == [OPSET]
    metadata = OnnxModel(tiny_onnx).metadata
    assert {key: metadata[key] for key in CARD} == CARD
    assert metadata["palette_sha256"] == file_sha256(DEFAULT_PALETTE)
    assert metadata["raster_function"] == "synthesis.raster.point_raster" and metadata["raster_size"] == 256
    assert metadata["generator"]["levels"] == 6 and metadata["generator"]["parameters"] > 0
    assert OnnxModel(tiny_onnx).points_per_ink == 8000


def test_exporter_keys_are_reserved(tiny_module, tmp_path):
    with pytest.raises(PatternshopError, match="raster_size"):
        export_onnx(tiny_module, tmp_path / "m.onnx", {"raster_size": 128})
    assert not list(tmp_path.iterdir())


def test_saturation_and_palette_warnings(tiny_module, tiny_onnx, tmp_path):
    model = OnnxModel(tiny_onnx)
    with pytest.warns(PatternshopWarning, match="saturated"):
        points_to_map(uniform_points(20_000), model, points_per_ink=10_000)
    other = tmp_path / "other.onnx"
    export_onnx(tiny_module, other, {"palette_sha256": "0" * 64})
    with pytest.warns(PatternshopWarning, match="another palette"):
        check_palette(OnnxModel(other))
    check_palette(model)  # the shipped palette: no warning (warnings are errors in the tests)


def test_pattern_scale_matches_training(tiny_onnx):
    """A pattern at points_per_ink P (per unit area) is rasterised at 256 sqrt(P / P_train) px per unit: same points per pixel."""
    model = OnnxModel(tiny_onnx)  # trained at 8000 points per ink
    square = uniform_points(20_000)
    b = DEFAULT_INFER.border_px
    raster, scale = pattern_raster(square, 256, 8000, 50_000)
    assert scale == pytest.approx(640) and raster.shape == (704, 704)  # 640 + 2 x 32 mirrored, a multiple of 64
    inside = raster[b : b + 640, b : b + 640]
    assert inside.sum() == pytest.approx(20_000, rel=0.02)  # the clip at 1 per pixel takes ~0.6 %
    # mean points per pixel = what a map of the same density (0.4) held in training: 0.4 * 8000 / 256^2
    assert inside.mean() == pytest.approx(0.4 * 8000 / 256**2, rel=0.01)
    same, scale_same = pattern_raster(square, 256, 8000, 8000)
    assert scale_same == pytest.approx(256) and same.shape == (320, 320)
    np.testing.assert_allclose(same[b + 1 : b + 255, b + 1 : b + 255], point_raster(square.xy)[1:255, 1:255], atol=1e-6)
    # the border is the pattern mirrored: column b - 1 - k holds what column b + k holds
    np.testing.assert_allclose(same[b + 1 : b + 255, b - 8 : b][:, ::-1], same[b + 1 : b + 255, b : b + 8], atol=0.02)
    # a non-square domain of area 0.5 at the same points per unit area: the same pixels per unit, padded to 64
    wide, scale_wide = pattern_raster(uniform_points(2_000, (1.0, 0.5)), 256, 8000, 8000)
    assert scale_wide == pytest.approx(256) and wide.shape == (320, 320)
    height, width = round(0.5 * scale_wide), round(scale_wide)
    assert wide[b + 1 : b + height - 1, b + 1 : b + width - 1].mean() == pytest.approx(2_000 / (0.5 * scale_wide**2), rel=0.05)
    # below the domain the canvas holds the pattern mirrored across its bottom side, to the canvas's end
    rows = np.arange(height - 2)
    np.testing.assert_allclose(wide[b + height + rows, b + 1 : b + width - 1], wide[b + height - 1 - rows, b + 1 : b + width - 1],
                               atol=0.02)
    assert wide[b + height :].shape[0] > height  # repeated reflections reach the canvas end: no empty band
    assert wide[-32:, b : b + width].mean() == pytest.approx(wide[b : b + height, b : b + width].mean(), rel=0.1)
    assert points_to_map(square, model).lab.shape == (256, 256, 3)


def test_mirror_images_fill_the_canvas_beyond_the_domain():
    """No empty band on the canvas's far sides: the network would read it as a density edge (grain at the map's rim)."""
    b = DEFAULT_INFER.border_px
    for domain in ((1.0, 1.0), (1.0, 0.3)):  # a pad of 19 px after the domain; and one wider than the domain itself
        points = uniform_points(60_000, domain, seed=3)
        raster, scale = pattern_raster(points, 256, 8000, 50_000)
        inside = raster[b : b + round(domain[1] * scale), b : b + round(domain[0] * scale)].mean()
        for band in (raster[:, -8:], raster[-8:, :], raster[:, :8], raster[:8, :]):
            assert band.mean() == pytest.approx(inside, rel=0.1)
    far = mirrored(PointSet(np.array([[0.1, 0.04]]), (1.0, 0.2)), 0.05, (0.05, 0.5))  # reflections repeat up to y 0.7
    assert sorted(np.round(far[:, 1], 6)) == [-0.04, 0.04, 0.36, 0.44] and np.all(far[:, 0] == 0.1)


def test_mirrored_points_reflect_across_each_side_and_corner():
    points = PointSet(np.array([[0.01, 0.5], [0.5, 0.98], [0.99, 0.01], [0.5, 0.5]]), (1.0, 1.0))
    images = mirrored(points, 0.05)
    expected = {(0.01, 0.5), (-0.01, 0.5), (0.5, 0.98), (0.5, 1.02), (0.99, 0.01), (1.01, 0.01), (0.99, -0.01), (1.01, -0.01), (0.5, 0.5)}
    assert {tuple(np.round(p, 6)) for p in images} == expected and len(images) == len(expected)


@pytest.mark.parametrize("domain", [(1.0, 0.5), (0.5, 1.0)])
def test_non_square_domain_is_padded_and_cropped(tiny_onnx, domain):
    model = OnnxModel(tiny_onnx)
    points = uniform_points(1500, domain)
    lab_map = points_to_map(points, model, points_per_ink=8000)
    w, h = domain
    assert (lab_map.width, lab_map.height) == (round(256 * w), round(256 * h))
    assert lab_map.domain == pytest.approx(domain)
    raster, scale = pattern_raster(points, 256, 8000, 8000)
    full = model.predict(raster[None, None])[0][:, DEFAULT_INFER.border_px:, DEFAULT_INFER.border_px:]
    native = points_to_map(points, model, width=round(w * scale), points_per_ink=8000)
    np.testing.assert_allclose(native.L, 100 * full[0, : native.height, : native.width], atol=1e-3)
    np.testing.assert_allclose(native.ab, 255 * full[1:, : native.height, : native.width].transpose(1, 2, 0) - 128, atol=1e-3)
    assert points_to_map(points, model, width=64).width == 64


def test_infer_writes_a_map(tiny_onnx, tmp_path, capsys):
    source = tmp_path / "pts.txt"
    write_points(uniform_points(1000, (1.0, 0.75)), source)
    status, err = run(["infer", str(source), str(tmp_path / "map.tif"), "--model", str(tiny_onnx),
                       "--preview", str(tmp_path / "map.png"), "--bits", "8"], capsys)
    assert status == 0, err
    assert read_map(tmp_path / "map.tif").lab.shape == (192, 256, 3)
    assert (tmp_path / "map.png").is_file()
    status, err = run(["infer", str(source), str(tmp_path / "ch.L.png"), "--model", str(tiny_onnx), "--width", "128"], capsys)
    assert status == 0, err
    assert read_map(tmp_path / "ch.a.png").lab.shape == (96, 128, 3)
    status, err = run(["infer", str(source), str(tmp_path / "sq.tif"), "--model", str(tiny_onnx), "--domain", "1", "1",
                       "--threads", "2"], capsys)
    assert status == 0, err
    assert read_map(tmp_path / "sq.tif").lab.shape == (256, 256, 3)


@pytest.mark.parametrize("content", [b"", b"not an onnx model" * 10, None])
def test_infer_bad_model_is_one_line_exit_2(content, tiny_onnx, tmp_path, capsys):
    source, output, model = tmp_path / "pts.txt", tmp_path / "map.tif", tmp_path / "model.onnx"
    write_points(uniform_points(100), source)
    if content is not None:
        model.write_bytes(content)
    status, err = run(["infer", str(source), str(output), "--model", str(model)], capsys)
    assert status == 2
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert f"patternshop infer: error: {model}: " in err
    assert ("no such model file" if content is None else "not a readable ONNX model") in err
    assert not output.exists()


def test_infer_without_default_model_says_how_to_get_one(tmp_path, capsys, monkeypatch):
    import export.runtime

    missing = tmp_path / "assets" / "default.onnx"
    monkeypatch.setattr(export.runtime, "DEFAULT_MODEL", missing)
    source = tmp_path / "pts.txt"
    write_points(uniform_points(100), source)
    status, err = run(["infer", str(source), str(tmp_path / "map.tif")], capsys)
    assert status == 2 and len(err.strip().splitlines()) == 1
    assert f"no default model at {missing}" in err and "python train.py" in err and "--model" in err


def test_export_command_from_a_checkpoint(tiny_module, tmp_path, capsys):
    checkpoint = tmp_path / "tiny.ckpt"
    torch.save({"state_dict": tiny_module.state_dict(), "hyper_parameters": dict(tiny_module.hparams),
                "pytorch-lightning_version": lightning.__version__}, checkpoint)
    output = tmp_path / "tiny.onnx"
    status, err = run(["export", str(checkpoint), str(output), "--name", "tiny", "--set", "points_per_ink=8000",
                       "--set", "license=MIT"], capsys)
    assert status == 0, err
    assert "max |torch - onnxruntime|" in err
    metadata = OnnxModel(output).metadata
    assert metadata["name"] == "tiny" and metadata["points_per_ink"] == 8000 and metadata["license"] == "MIT"
    assert metadata["checkpoint_sha256"] == file_sha256(checkpoint)
    (tmp_path / "bad.ckpt").write_bytes(b"garbage" * 10)
    status, err = run(["export", str(tmp_path / "bad.ckpt"), str(tmp_path / "bad.onnx")], capsys)
    assert status == 2 and "not a Pix2PixModule checkpoint" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "bad.onnx").exists()
