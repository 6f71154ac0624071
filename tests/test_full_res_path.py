"""The optional full-resolution path of the density decoder (``model.full_res_channels``, ``model.full_res_stride``)."""

from __future__ import annotations

import numpy as np
import onnxruntime
import pytest
import torch

from patternshop_nn.module import Pix2PixModule
from patternshop_nn.onnx_export import export_onnx
from patternshop_nn.onnx_import import checkpoint_from_onnx, generator_from_onnx
from patternshop_nn.train import load_weights
from synthesis.errors import PatternshopError


def tiny(full_res: int, stride: int = 1) -> Pix2PixModule:
    torch.manual_seed(0)
    return Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, upsample="nearest", l_scale=True,
                         full_res_channels=full_res, full_res_stride=stride)


def rasters() -> torch.Tensor:
    return (torch.rand(2, 1, 64, 64, generator=torch.Generator().manual_seed(1)) < 0.1).float()


@pytest.mark.parametrize("stride", [1, 4])
def test_a_model_without_the_path_loads_into_one_with_it_unchanged_and_the_path_then_learns(tmp_path, stride):
    plain = tiny(0)
    checkpoint = tmp_path / "plain.ckpt"
    torch.save({"state_dict": plain.state_dict()}, checkpoint)
    refined = tiny(8, stride)
    load_weights(refined, checkpoint)
    x = rasters()
    with torch.no_grad():
        for a, b in zip(plain.generator.eval().forward_with_scale(x), refined.generator.eval().forward_with_scale(x), strict=True):
            torch.testing.assert_close(a, b)
    # the zero convolution gets a gradient at once, so training moves L through the path
    lab, scale = refined.generator.train().forward_with_scale(x)
    lab[:, :1].sum().backward()
    assert refined.generator.refine.weight.grad.abs().sum() > 0
    # anything else missing is still refused
    broken = {k: v for k, v in plain.state_dict().items() if not k.startswith("generator.first.")}
    torch.save({"state_dict": broken}, tmp_path / "broken.ckpt")
    with pytest.raises(PatternshopError, match="does not fit"):
        load_weights(tiny(8), tmp_path / "broken.ckpt")


@pytest.mark.parametrize("stride", [1, 2])
def test_the_path_changes_l_only_is_exported_and_rebuilt_from_the_export(tmp_path, stride):
    net = tiny(8, stride).generator.eval()
    torch.nn.init.normal_(net.refine.weight, 0.0, 0.5)
    x = rasters()
    with torch.no_grad():
        lab, scale = net.forward_with_scale(x)
        net.full_res_channels = 0  # the same network read without its path
        base = net.forward_with_scale(x)
        net.full_res_channels = 8
    assert (lab[:, :1] - base[0][:, :1]).abs().max() > 1e-3
    torch.testing.assert_close(lab[:, 1:], base[0][:, 1:])
    torch.testing.assert_close(scale, base[1])
    export_onnx(net, tmp_path / "full_res.onnx", {"points_per_ink": 8000})
    session = onnxruntime.InferenceSession(str(tmp_path / "full_res.onnx"), providers=["CPUExecutionProvider"])
    exported, _ = session.run(None, {"raster": x.numpy()})
    assert np.abs(exported - lab.numpy()).max() < 1e-4
    rebuilt = generator_from_onnx(tmp_path / "full_res.onnx", base_channels=4, max_channels=8, l_scale=True)
    assert (rebuilt.full_res_channels, rebuilt.full_res_stride) == (8, stride)
    with torch.no_grad():
        torch.testing.assert_close(rebuilt.forward_with_scale(x)[0], lab, atol=1e-4, rtol=0)


@pytest.mark.parametrize("stride", [1, 2])
def test_a_checkpoint_rebuilt_from_an_export_with_the_path_exports_the_same_function(tmp_path, stride):
    """python -m patternshop_nn.onnx_import's checkpoint of a model with the path: the module and its recorded
    hyper-parameters take the path, so `patternshop export` of it gives the exported model back."""
    net = tiny(8, stride).generator.eval()
    torch.nn.init.normal_(net.refine.weight, 0.0, 0.5)
    export_onnx(net, tmp_path / "full_res.onnx", {"points_per_ink": 8000})
    checkpoint = checkpoint_from_onnx(tmp_path / "full_res.onnx", tmp_path / "rebuilt.ckpt", base_channels=4,
                                      max_channels=8, disc_channels=4, l_scale=True)
    recorded = torch.load(checkpoint, weights_only=False)["hyper_parameters"]
    assert (recorded["full_res_channels"], recorded["full_res_stride"]) == (8, stride)
    export_onnx(checkpoint, tmp_path / "again.onnx", {"points_per_ink": 8000})
    x = rasters().numpy()
    first, again = (onnxruntime.InferenceSession(str(tmp_path / name), providers=["CPUExecutionProvider"]).run(None, {"raster": x})
                    for name in ("full_res.onnx", "again.onnx"))
    for a, b in zip(first, again, strict=True):
        assert np.abs(a - b).max() < 1e-5


def test_the_path_learns_at_its_own_rate():
    module = Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, l_scale=True, full_res_channels=4,
                           lr=3e-5, l_scale_lr=1e-3, full_res_lr=2e-3)
    (generator_optimizer, _), _ = module.configure_optimizers()
    rates = {id(p): group["lr"] for group in generator_optimizer.param_groups for p in group["params"]}
    assert rates[id(module.generator.refine.weight)] == rates[id(module.generator.full_res[0].weight)] == 2e-3
    assert rates[id(module.generator.first.weight)] == 3e-5 and len(rates) == len(list(module.generator.parameters()))


def test_the_strided_path_reads_and_corrects_each_pixel_of_its_blocks():
    """Stride k: the path's convolutions see block (I, J)'s pixel (i, j) as channel i k + j, and its correction of
    that channel lands on raster pixel (I k + i, J k + j): checked against the same layers applied to slices."""
    k = 4
    net = tiny(8, k).generator.eval()
    torch.nn.init.normal_(net.refine.weight, 0.0, 0.5)
    raster, logit = rasters(), torch.randn(2, 1, 64, 64, generator=torch.Generator().manual_seed(2))
    offsets = [(i, j) for i in range(k) for j in range(k)]
    with torch.no_grad():
        blocks = torch.cat([torch.cat([raster[..., i::k, j::k] for i, j in offsets], 1),
                            torch.cat([logit[..., i::k, j::k] for i, j in offsets], 1)], 1)
        blocks = torch.cat([net.full_res(blocks[:, : k * k]), blocks[:, k * k :]], 1)
        correction = net.refine(blocks)
        expected = logit.clone()
        for channel, (i, j) in enumerate(offsets):
            expected[..., i::k, j::k] += correction[:, channel : channel + 1]
        refined = net._refined(raster, logit)
    torch.testing.assert_close(refined, expected)
    within = (refined - logit).unfold(2, k, k).unfold(3, k, k)  # (B, 1, 16, 16, k, k): each block's corrections
    assert within.std(dim=(-1, -2)).min() > 1e-3  # a correction per pixel, not one per block


def test_a_stride_that_does_not_divide_the_raster_side_factor_is_refused():
    with pytest.raises(ValueError, match="full_res_stride"):
        tiny(8, 3)
