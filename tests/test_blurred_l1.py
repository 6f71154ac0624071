"""The optional blurred L1 term of L (``model.blurred_l1_weight``): the density error a few point spacings wide."""

from __future__ import annotations

import numpy as np
import torch
from scipy.ndimage import gaussian_filter

from patternshop_nn.module import Pix2PixModule
from patternshop_nn.networks import blurred_l1, gaussian_blur


def test_gaussian_blur_is_scipys_gaussian_filter_with_edges_replicated():
    maps = torch.rand(2, 3, 40, 48, dtype=torch.float64)
    blurred = gaussian_blur(maps, 4.0).numpy()
    reference = gaussian_filter(maps.numpy(), sigma=(0, 0, 4.0, 4.0), mode="nearest", truncate=3.0)
    np.testing.assert_allclose(blurred, reference, atol=1e-12)


def test_blurred_l1_is_zero_for_equal_maps_and_weighs_contrast_more_than_pixel_noise():
    torch.manual_seed(0)
    truth = torch.rand(2, 1, 64, 64)
    assert float(blurred_l1(truth, truth.clone(), 4.0)) == 0.0
    wave = 0.5 + 0.1 * torch.sin(torch.arange(64) * 2 * np.pi / 32).view(1, 1, 64, 1).expand(2, 1, 64, 64)
    noise = 0.1 * torch.sign(torch.randn(2, 1, 64, 64))  # per-pixel error of the same L1 (0.1), no contrast lost
    flat = torch.full_like(wave, 0.5)  # the wave's contrast lost: per-pixel L1 0.064
    assert float(blurred_l1(wave + noise, wave, 4.0)) < 0.02 < 0.04 < float(blurred_l1(flat, wave, 4.0))


def losses(weight: float, fake: torch.Tensor, scale: torch.Tensor | None, target: torch.Tensor) -> tuple[torch.Tensor, dict]:
    module = Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, l_scale=scale is not None, l_nll_weight=0.05,
                           blurred_l1_weight=weight, blurred_l1_sigma_px=2.0)
    return module.reconstruction_loss(fake, scale, target)


def test_the_term_reaches_only_l_and_weight_zero_leaves_the_loss_unchanged():
    torch.manual_seed(1)
    target = torch.rand(2, 3, 32, 32)
    for with_scale in (True, False):
        fake = torch.rand(2, 3, 32, 32, requires_grad=True)
        scale = (0.01 + 0.1 * torch.rand(2, 1, 32, 32)).requires_grad_(True) if with_scale else None
        plain, parts = losses(0.0, fake, scale, target)
        assert "l_blurred_l1" not in parts
        if with_scale:  # the v6 loss as before: (l_nll_weight x NLL of L + 2 x L1 of a, b) / 3
            nll = ((target[:, :1] - fake[:, :1]).abs() / scale + torch.log(scale)).mean()
            expected = (0.05 * nll + 2.0 * (fake[:, 1:] - target[:, 1:]).abs().mean()) / 3.0
        else:
            expected = (fake - target).abs().mean()
        assert torch.equal(plain, expected)
        weighted, parts = losses(0.5, fake, scale, target)
        assert float(parts["l_blurred_l1"].detach()) > 0.0
        torch.testing.assert_close(weighted - plain, 0.5 * parts["l_blurred_l1"])
        inputs = (fake, scale) if with_scale else (fake,)
        gradients = torch.autograd.grad(parts["l_blurred_l1"], inputs, allow_unused=True)
        assert gradients[0][:, :1].abs().sum() > 0 and gradients[0][:, 1:].abs().sum() == 0
        if with_scale:
            assert gradients[1] is None or gradients[1].abs().sum() == 0
