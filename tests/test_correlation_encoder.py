"""The correlation decoder's own encoder (``model.correlation_encoder``, ``DualBranchUNet.own_correlation_encoder``)."""

from __future__ import annotations

import numpy as np
import onnxruntime
import pytest
import torch

from patternshop_nn.module import Pix2PixModule
from patternshop_nn.onnx_export import export_onnx
from patternshop_nn.onnx_import import checkpoint_from_onnx, generator_from_onnx


def tiny() -> Pix2PixModule:
    torch.manual_seed(0)
    return Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, upsample="nearest", l_scale=True,
                         full_res_channels=4, full_res_stride=2)


def rasters() -> torch.Tensor:
    return (torch.rand(2, 1, 64, 64, generator=torch.Generator().manual_seed(1)) < 0.1).float()


def owning(module: Pix2PixModule, shared_levels: int = 0) -> torch.nn.Module:
    """The module's generator with an own correlation encoder, moved off the copy so that it differs from the shared one."""
    generator = module.generator.eval()
    generator.own_correlation_encoder(shared_levels)
    with torch.no_grad():
        for p in generator.correlation_encoder.parameters():
            p.add_(0.3 * torch.randn_like(p))
    return generator


SHARED_LEVELS = pytest.mark.parametrize("shared_levels", [0, 2])  # all its own; its first two levels the shared ones


@SHARED_LEVELS
def test_the_copy_starts_at_the_models_function_and_then_moves_a_b_only(shared_levels):
    module = tiny()
    generator = module.generator.eval()
    x = rasters()
    with torch.no_grad():
        lab, scale = generator.forward_with_scale(x)
        generator.own_correlation_encoder(shared_levels)
        copied = generator.forward_with_scale(x)
        owning(module)
        moved = generator.forward_with_scale(x)
    torch.testing.assert_close(copied[0], lab, rtol=0, atol=0)
    torch.testing.assert_close(moved[0][:, :1], lab[:, :1], rtol=0, atol=0)  # L and its scale: bit for bit
    torch.testing.assert_close(moved[1], scale, rtol=0, atol=0)
    assert (moved[0][:, 1:] - lab[:, 1:]).abs().max() > 1e-5  # (an untrained net: a, b near 0.5 and small moves)
    torch.testing.assert_close(generator(x), moved[0], rtol=0, atol=0)  # forward and forward_with_scale agree
    own = generator.correlation_encoder
    assert (own.first is None) == (shared_levels > 0)
    assert sum(isinstance(down, torch.nn.Identity) for down in own.downs) == max(0, shared_levels - 1)
    if shared_levels:  # the shared levels' features are the shared encoder's own tensors
        shared = generator._encode(x)
        assert all(a is b for a, b in zip(generator.correlation_features(x, shared)[:shared_levels], shared, strict=False))
        with pytest.raises(ValueError, match="shared levels"):
            own(x)


@SHARED_LEVELS
def test_an_export_with_its_own_encoder_is_rebuilt_and_exports_the_same_function(tmp_path, shared_levels):
    module = tiny()
    generator = owning(module, shared_levels)
    x = rasters()
    export_onnx(generator, tmp_path / "own.onnx", {"points_per_ink": 8000})
    session = onnxruntime.InferenceSession(str(tmp_path / "own.onnx"), providers=["CPUExecutionProvider"])
    with torch.no_grad():
        lab, _ = generator.forward_with_scale(x)
    assert np.abs(session.run(None, {"raster": x.numpy()})[0] - lab.numpy()).max() < 1e-4
    rebuilt = generator_from_onnx(tmp_path / "own.onnx", base_channels=4, max_channels=8, l_scale=True)
    assert rebuilt.correlation_encoder is not None and rebuilt.correlation_encoder.shared_levels == shared_levels
    with torch.no_grad():
        torch.testing.assert_close(rebuilt.forward_with_scale(x)[0], lab, atol=1e-4, rtol=0)
    checkpoint = checkpoint_from_onnx(tmp_path / "own.onnx", tmp_path / "rebuilt.ckpt", rasters=x, base_channels=4,
                                      max_channels=8, disc_channels=4, l_scale=True)
    hparams = torch.load(checkpoint, weights_only=False)["hyper_parameters"]
    assert hparams["correlation_encoder"] and hparams["correlation_shared_levels"] == shared_levels
    export_onnx(checkpoint, tmp_path / "again.onnx", {"points_per_ink": 8000})
    again = onnxruntime.InferenceSession(str(tmp_path / "again.onnx"), providers=["CPUExecutionProvider"])
    for a, b in zip(session.run(None, {"raster": x.numpy()}), again.run(None, {"raster": x.numpy()}), strict=True):
        assert np.abs(a - b).max() < 1e-5


def test_a_coarse_correlation_decoder_keeps_l_exports_and_is_rebuilt(tmp_path):
    module = tiny()
    generator = owning(module)
    x = rasters()
    with torch.no_grad():
        lab, scale = generator.forward_with_scale(x)
        generator.coarse_correlation_decoder(8)
        for p in generator.correlation.head.parameters():
            p.add_(0.3 * torch.randn_like(p))
        coarse, coarse_scale = generator.forward_with_scale(x)
    assert coarse.shape == lab.shape and generator.correlation.stride == 8 and len(generator.correlation.ups) == 3
    torch.testing.assert_close(coarse[:, :1], lab[:, :1], rtol=0, atol=0)  # L and its scale untouched
    torch.testing.assert_close(coarse_scale, scale, rtol=0, atol=0)
    with torch.no_grad():  # the head reads S/8 (its skip level, 2)
        assert generator.correlation.last_features(generator.correlation_features(x)).shape[-1] == x.shape[-1] // 8
    with pytest.raises(ValueError, match="coarsened only from S"):
        generator.coarse_correlation_decoder(4)
    export_onnx(generator, tmp_path / "coarse.onnx", {"points_per_ink": 8000})
    session = onnxruntime.InferenceSession(str(tmp_path / "coarse.onnx"), providers=["CPUExecutionProvider"])
    assert np.abs(session.run(None, {"raster": x.numpy()})[0] - coarse.numpy()).max() < 1e-4
    rebuilt = generator_from_onnx(tmp_path / "coarse.onnx", base_channels=4, max_channels=8, l_scale=True)
    assert rebuilt.correlation.stride == 8
    with torch.no_grad():
        torch.testing.assert_close(rebuilt.forward_with_scale(x)[0], coarse, atol=1e-4, rtol=0)
    checkpoint = checkpoint_from_onnx(tmp_path / "coarse.onnx", tmp_path / "rebuilt.ckpt", rasters=x, base_channels=4,
                                      max_channels=8, disc_channels=4, l_scale=True)
    assert torch.load(checkpoint, weights_only=False)["hyper_parameters"]["correlation_stride"] == 8
