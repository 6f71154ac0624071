"""The correlation decoder's own encoder (``model.correlation_encoder``, ``DualBranchUNet.own_correlation_encoder``)."""

from __future__ import annotations

import numpy as np
import onnxruntime
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


def owning(module: Pix2PixModule) -> torch.nn.Module:
    """The module's generator with an own correlation encoder, moved off the copy so that it differs from the shared one."""
    generator = module.generator.eval()
    generator.own_correlation_encoder()
    with torch.no_grad():
        for p in generator.correlation_encoder.parameters():
            p.add_(0.3 * torch.randn_like(p))
    return generator


def test_the_copy_starts_at_the_models_function_and_then_moves_a_b_only():
    module = tiny()
    generator = module.generator.eval()
    x = rasters()
    with torch.no_grad():
        lab, scale = generator.forward_with_scale(x)
        generator.own_correlation_encoder()
        copied = generator.forward_with_scale(x)
        owning(module)
        moved = generator.forward_with_scale(x)
    torch.testing.assert_close(copied[0], lab, rtol=0, atol=0)
    torch.testing.assert_close(moved[0][:, :1], lab[:, :1], rtol=0, atol=0)  # L and its scale: bit for bit
    torch.testing.assert_close(moved[1], scale, rtol=0, atol=0)
    assert (moved[0][:, 1:] - lab[:, 1:]).abs().max() > 1e-3
    torch.testing.assert_close(generator(x), moved[0], rtol=0, atol=0)  # forward and forward_with_scale agree


def test_an_export_with_its_own_encoder_is_rebuilt_and_exports_the_same_function(tmp_path):
    module = tiny()
    generator = owning(module)
    x = rasters()
    export_onnx(generator, tmp_path / "own.onnx", {"points_per_ink": 8000})
    session = onnxruntime.InferenceSession(str(tmp_path / "own.onnx"), providers=["CPUExecutionProvider"])
    with torch.no_grad():
        lab, _ = generator.forward_with_scale(x)
    assert np.abs(session.run(None, {"raster": x.numpy()})[0] - lab.numpy()).max() < 1e-4
    rebuilt = generator_from_onnx(tmp_path / "own.onnx", base_channels=4, max_channels=8, l_scale=True)
    assert rebuilt.correlation_encoder is not None
    with torch.no_grad():
        torch.testing.assert_close(rebuilt.forward_with_scale(x)[0], lab, atol=1e-4, rtol=0)
    checkpoint = checkpoint_from_onnx(tmp_path / "own.onnx", tmp_path / "rebuilt.ckpt", rasters=x, base_channels=4,
                                      max_channels=8, disc_channels=4, l_scale=True)
    assert torch.load(checkpoint, weights_only=False)["hyper_parameters"]["correlation_encoder"]
    export_onnx(checkpoint, tmp_path / "again.onnx", {"points_per_ink": 8000})
    again = onnxruntime.InferenceSession(str(tmp_path / "again.onnx"), providers=["CPUExecutionProvider"])
    for a, b in zip(session.run(None, {"raster": x.numpy()}), again.run(None, {"raster": x.numpy()}), strict=True):
        assert np.abs(a - b).max() < 1e-5
