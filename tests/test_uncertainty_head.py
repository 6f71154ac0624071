"""Network v6's uncertainty head (issue 28): the Laplace scale of L, its loss, its ONNX output, and the generator
rebuilt from an exported model (patternshop_nn/onnx_import.py) to fine-tune from."""

from __future__ import annotations

import numpy as np
import onnxruntime
import pytest
import torch

from patternshop_nn.module import Pix2PixModule
from patternshop_nn.networks import L_SCALE_MIN, DualBranchUNet, laplace_nll
from export.runtime import L_SCALE_NAME
from patternshop_nn.onnx_export import export_onnx
from patternshop_nn.onnx_import import calibrate_folded_norms, checkpoint_from_onnx, generator_from_onnx, unfuse_kernel
from synthesis.errors import PatternshopError


def rasters(count: int = 2, side: int = 64, seed: int = 0) -> torch.Tensor:
    return torch.from_numpy((np.random.default_rng(seed).random((count, 1, side, side)) < 0.1).astype(np.float32))


def test_scale_head_shapes_and_the_map_is_unchanged_by_it():
    torch.manual_seed(0)
    net = DualBranchUNet(base_channels=4, max_channels=8, upsample="nearest", l_scale=True).eval()
    x = rasters()
    with torch.no_grad():
        lab, scale = net.forward_with_scale(x)
        np.testing.assert_array_equal(lab.numpy(), net(x).numpy())
    assert lab.shape == (2, 3, 64, 64) and scale.shape == (2, 1, 64, 64)
    assert float(scale.min()) >= L_SCALE_MIN and float(lab.min()) >= 0 and float(lab.max()) <= 1
    with pytest.raises(ValueError, match="no l_scale head"):
        DualBranchUNet(base_channels=4, max_channels=8).forward_with_scale(x)


def test_laplace_nll_is_smallest_at_the_absolute_error():
    target, mean = torch.tensor([0.3, 0.9, 0.5]), torch.tensor([0.1, 0.85, 0.5])
    error = (target - mean).abs()
    scales = torch.linspace(0.001, 0.5, 5000)
    nll = laplace_nll(target[:, None], mean[:, None], scales[None, :])
    best = scales[nll.argmin(dim=1)]
    np.testing.assert_allclose(best[:2].numpy(), error[:2].numpy(), atol=2e-4)
    assert best[2] == scales[0]  # no error: as small as allowed
    scale = torch.full((3,), 0.07, requires_grad=True)
    laplace_nll(target, mean, scale).sum().backward()
    assert scale.grad[0] < 0 < scale.grad[1]  # error 0.2 > 0.07: grow; error 0.05 < 0.07: shrink


def test_head_loss_trains_the_scale_towards_the_error():
    torch.manual_seed(0)
    module = Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, upsample="nearest", l_scale=True, l_nll_weight=0.5)
    x = rasters(4)
    target = torch.rand(4, 3, 64, 64)
    optimiser = torch.optim.Adam(module.generator.parameters(), lr=3e-3)
    losses = []
    for _ in range(40):
        lab, scale = module.generator.forward_with_scale(x)
        loss, parts = module.reconstruction_loss(lab, scale, target)
        assert set(parts) == {"l1", "l_nll"}
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < losses[0] - 0.05
    with torch.no_grad():
        lab, scale = module.generator.eval().forward_with_scale(x)
    error = (lab[:, :1] - target[:, :1]).abs().mean()
    assert 0.5 * error < scale.mean() < 2.0 * error  # the mean scale came near the mean absolute error


def test_with_l_mean_l1_the_mean_learns_from_its_l1_and_the_scale_from_the_nll():
    torch.manual_seed(2)
    target = torch.rand(2, 3, 16, 16)
    fake = torch.rand(2, 3, 16, 16, requires_grad=True)
    scale = (0.01 + 0.3 * torch.rand(2, 1, 16, 16)).requires_grad_(True)
    gradients = {}
    for detached in (False, True):
        module = Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, l_scale=True, l_nll_weight=0.05,
                               l_mean_l1=detached)
        loss, parts = module.reconstruction_loss(fake, scale, target)
        gradients[detached] = torch.autograd.grad(loss, (fake, scale))
    error_sign = torch.sign(fake[:, :1] - target[:, :1]).detach()
    pixels = error_sign.numel()
    # the NLL's mean gradient is weighted by 1 / b; the L1's is the same for every pixel
    torch.testing.assert_close(gradients[False][0][:, :1], 0.05 * error_sign / scale.detach() / pixels / 3.0)
    torch.testing.assert_close(gradients[True][0][:, :1], error_sign / pixels / 3.0)
    torch.testing.assert_close(gradients[True][0][:, 1:], gradients[False][0][:, 1:])  # a, b as before
    torch.testing.assert_close(gradients[True][1], gradients[False][1])  # the scale learns from the same NLL


def test_export_has_map_and_l_scale_outputs(tmp_path):
    torch.manual_seed(0)
    net = DualBranchUNet(base_channels=4, max_channels=8, upsample="nearest", l_scale=True)
    props = export_onnx(net, tmp_path / "head.onnx", {"points_per_ink": 8000})
    assert set(props["outputs"]) == {"map", L_SCALE_NAME} == {"map", "l_scale"}
    session = onnxruntime.InferenceSession(str(tmp_path / "head.onnx"), providers=["CPUExecutionProvider"])
    assert [o.name for o in session.get_outputs()] == ["map", "l_scale"]
    assert "l_scale" in session.get_modelmeta().custom_metadata_map["outputs"]
    x = rasters(3, 128)
    lab, scale = session.run(None, {"raster": x.numpy()})
    assert lab.shape == (3, 3, 128, 128) and scale.shape == (3, 1, 128, 128)
    with torch.no_grad():
        expected_lab, expected_scale = net.eval().forward_with_scale(x)
    assert np.abs(lab - expected_lab.numpy()).max() < 1e-4 and np.abs(scale - expected_scale.numpy()).max() < 1e-5
    export_onnx(net, tmp_path / "map_only.onnx", l_scale=False)
    only = onnxruntime.InferenceSession(str(tmp_path / "map_only.onnx"), providers=["CPUExecutionProvider"])
    assert [o.name for o in only.get_outputs()] == ["map"]


def test_unfusing_inverts_the_fused_kernels():
    from patternshop_nn.networks import NearestUpConv

    conv = torch.nn.Conv2d(3, 2, 3, 1, 1)
    fused = NearestUpConv(conv).weight.numpy()
    np.testing.assert_allclose(unfuse_kernel(fused), conv.weight.detach().numpy(), atol=1e-6)


def test_generator_rebuilt_from_onnx_computes_the_exported_function(tmp_path):
    torch.manual_seed(1)
    module = Pix2PixModule(levels=3, base_channels=4, max_channels=8, disc_channels=4, upsample="nearest")
    x = rasters(4, 64, seed=3)
    module.generator.train()
    with torch.no_grad():  # batch statistics away from the initial ones, so that folding changes the weights
        for seed in range(3):
            module.generator(rasters(4, 64, seed=seed) * 3)
    export_onnx(module, tmp_path / "g.onnx")
    expected = onnxruntime.InferenceSession(str(tmp_path / "g.onnx"), providers=["CPUExecutionProvider"]).run(None, {"raster": x.numpy()})[0]
    rebuilt = generator_from_onnx(tmp_path / "g.onnx", levels=3, base_channels=4, max_channels=8, l_scale=True)
    calibrate_folded_norms(rebuilt, x)
    with torch.no_grad():
        lab, scale = rebuilt.eval().forward_with_scale(x)
    assert np.abs(lab.numpy() - expected).max() < 1e-4
    assert abs(float(scale.mean()) - 0.05) < 0.01 and float(scale.std()) < 0.01  # the new head starts near 0.05
    norm = rebuilt.downs[0][2]
    assert not torch.allclose(norm.weight, torch.ones_like(norm.weight))  # calibrated statistics
    path = checkpoint_from_onnx(tmp_path / "g.onnx", tmp_path / "g.ckpt", x, levels=3, base_channels=4, max_channels=8,
                                disc_channels=4, l_scale=True)
    tuned = Pix2PixModule(levels=3, base_channels=4, max_channels=8, disc_channels=4, upsample="nearest", l_scale=True)
    tuned.load_state_dict(torch.load(path, weights_only=False)["state_dict"])  # what train.py init_from= does
    with torch.no_grad():
        assert np.abs(tuned.generator.eval()(x).numpy() - expected).max() < 1e-4
    with pytest.raises(PatternshopError, match="not an exported generator"):
        generator_from_onnx(tmp_path / "g.onnx", levels=4, base_channels=4, max_channels=8)


def test_a_model_exported_with_its_head_is_rebuilt_with_that_head(tmp_path):
    """The shipped models since v6 carry the l_scale output (layers named generator.*): both outputs come back."""
    torch.manual_seed(2)
    module = Pix2PixModule(levels=3, base_channels=4, max_channels=8, disc_channels=4, upsample="nearest", l_scale=True)
    module.generator.train()
    with torch.no_grad():
        for seed in range(3):
            module.generator(rasters(4, 64, seed=seed) * 3)
        module.generator.scale[-1].bias.fill_(1.0)  # a head unlike a new one (which starts near 0.05)
    export_onnx(module, tmp_path / "g.onnx")
    x = rasters(4, 64, seed=4)
    session = onnxruntime.InferenceSession(str(tmp_path / "g.onnx"), providers=["CPUExecutionProvider"])
    assert [o.name for o in session.get_outputs()] == ["map", "l_scale"]
    expected_map, expected_scale = session.run(None, {"raster": x.numpy()})
    rebuilt = generator_from_onnx(tmp_path / "g.onnx", levels=3, base_channels=4, max_channels=8, l_scale=True)
    with torch.no_grad():
        lab, scale = rebuilt.eval().forward_with_scale(x)
    assert np.abs(lab.numpy() - expected_map).max() < 1e-4
    assert np.abs(scale.numpy() - expected_scale).max() < 1e-5
    assert float(scale.mean()) > 0.5


def test_scale_head_has_its_own_learning_rate_and_the_map_layers_are_v5s():
    module = Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, upsample="nearest", l_scale=True, lr=1e-4, l_scale_lr=2e-3)
    plain = Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, upsample="nearest")
    extra = set(module.generator.state_dict()) - set(plain.generator.state_dict())
    assert extra and all(name.startswith("scale.") for name in extra)  # the map's layers are a plain generator's
    generator_optimiser = module.configure_optimizers()[0][0]
    rates = sorted(group["lr"] for group in generator_optimiser.param_groups)
    assert rates == [1e-4, 2e-3]
    head = {id(p) for p in module.generator.scale.parameters()}
    assert {id(p) for p in generator_optimiser.param_groups[1]["params"]} == head
    assert sum(len(group["params"]) for group in generator_optimiser.param_groups) == len(list(module.generator.parameters()))
