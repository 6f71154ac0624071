"""int8 quantization of an exported model (:mod:`patternshop_nn.quantize`), compared with the float model it came from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from data_gen.shards import Pairs, shard_path
from export.runtime import OnnxModel
from patternshop_nn.networks import DualBranchUNet
from patternshop_nn.onnx_export import export_onnx
from patternshop_nn.quantize import fine_convolutions, main, max_output_difference, quantize_model
from synthesis.errors import PatternshopError
from synthesis.raster import point_raster


def rasters(count: int, side: int, seed: int) -> np.ndarray:
    """(count, side, side) float32 point rasters of uniform random patterns, 2,000-6,000 points."""
    rng = np.random.default_rng(seed)
    return np.stack([point_raster(rng.random((int(rng.integers(2_000, 6_000)), 2)), side) for _ in range(count)])


@pytest.fixture(scope="module")
def float_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "tiny.onnx"
    export_onnx(DualBranchUNet(base_channels=4, max_channels=8, upsample="nearest", l_scale=True), path, {"name": "tiny"})
    return path


@pytest.fixture(scope="module")
def pairs_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("pairs")
    raster = rasters(6, 64, seed=1).astype(np.float16)
    Pairs(np.arange(6), raster, np.zeros((6, 64, 64, 3), np.uint8), np.zeros((6, 2), np.float32),
          np.arange(7)).write(shard_path(folder, 0))
    return folder


def test_fine_convolutions_are_those_at_a_quarter_of_the_side_or_finer(float_model):
    kept = fine_convolutions(float_model)
    # the first two of the encoder, the last up-sampling of each decoder, the three heads (map, correlation, scale)
    assert len(kept) == 7 and "/first/Conv" in kept
    assert not any(name.startswith(("/downs.1/", "/ups.0/", "/correlation/ups.0/")) for name in kept)


def test_quantized_model_stays_close_to_its_float_reference(float_model, pairs_dir, tmp_path):
    target = tmp_path / "int8.onnx"
    entry = quantize_model(float_model, target, [pairs_dir], count=4)
    model = OnnxModel(target)
    assert model.has_l_scale and model.metadata["name"] == "tiny" and model.metadata["quantized"] == entry
    assert entry["calibration_rasters"] == 4 and entry["float_convolutions"] == fine_convolutions(float_model)
    assert any(node.op_type == "QuantizeLinear" for node in onnx.load(str(target)).graph.node)
    difference = max_output_difference(float_model, target, rasters(2, 128, seed=2)[:, None])
    assert 0.0 < difference < 0.01  # quantized (not the float graph), and close to it (0.0005 when written)


def test_quantize_without_pairs_is_one_line_exit_2(float_model, tmp_path, capsys):
    assert main([str(float_model), str(tmp_path / "int8.onnx"), "--pairs", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no pair shards" in err and not (tmp_path / "int8.onnx").exists()
    not_a_model = tmp_path / "bad.onnx"
    not_a_model.write_bytes(b"not onnx")
    with pytest.raises(PatternshopError, match="not a readable ONNX model"):
        quantize_model(not_a_model, tmp_path / "int8.onnx", [tmp_path])
