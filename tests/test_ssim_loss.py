"""The optional SSIM term of L (``model.ssim_weight``): the loss scores local contrast and structure, as the figures do."""

from __future__ import annotations

import numpy as np
import torch
from skimage.metrics import structural_similarity as skimage_ssim

from patternshop_nn.module import Pix2PixModule
from patternshop_nn.networks import gaussian_blur, structural_similarity


def test_structural_similarity_is_scikit_images_default():
    rng = np.random.default_rng(0)
    truth = gaussian_blur(torch.from_numpy(rng.random((1, 1, 48, 40))), 2.0)[0, 0].numpy()
    for predicted in (truth, truth + 0.05 * rng.standard_normal(truth.shape), np.full_like(truth, truth.mean()),
                      rng.random(truth.shape)):
        ours = structural_similarity(torch.from_numpy(predicted)[None, None], torch.from_numpy(truth)[None, None])
        assert abs(float(ours) - skimage_ssim(truth, predicted, data_range=1.0)) < 1e-9
    scaled = structural_similarity(torch.from_numpy(100 * truth[::-1].copy())[None, None], torch.from_numpy(100 * truth)[None, None],
                                   data_range=100.0)
    assert abs(float(scaled) - skimage_ssim(100 * truth, 100 * truth[::-1], data_range=100.0)) < 1e-9


def test_ssim_prefers_kept_detail_to_its_blur_where_l1_prefers_the_blur():
    """A texture read with pixel noise: L1 calls the local mean (a blur) better, SSIM the detailed reading."""
    torch.manual_seed(0)
    stripes = 0.5 + 0.2 * torch.sign(torch.sin(torch.arange(64) * 2 * np.pi / 8)).view(1, 1, 1, 64).expand(1, 1, 64, 64)
    detailed = stripes + 0.25 * torch.sign(torch.randn(1, 1, 64, 64))
    blurred = gaussian_blur(stripes, 3.0)
    assert (blurred - stripes).abs().mean() < (detailed - stripes).abs().mean()
    assert structural_similarity(detailed, stripes) > structural_similarity(blurred, stripes)


def test_the_term_reaches_only_l_and_weight_zero_leaves_the_loss_unchanged():
    torch.manual_seed(1)
    target = torch.rand(2, 3, 32, 32)
    fake = torch.rand(2, 3, 32, 32, requires_grad=True)
    scale = (0.01 + 0.1 * torch.rand(2, 1, 32, 32)).requires_grad_(True)

    def loss(weight: float) -> tuple[torch.Tensor, dict]:
        module = Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, l_scale=True, l_nll_weight=0.05,
                               blurred_l1_weight=0.4, ssim_weight=weight)
        return module.reconstruction_loss(fake, scale, target)

    plain, parts = loss(0.0)
    assert "l_ssim" not in parts
    weighted, parts = loss(0.7)
    torch.testing.assert_close(weighted - plain, 0.7 * (1.0 - parts["l_ssim"]))
    fake_gradient, scale_gradient = torch.autograd.grad(parts["l_ssim"], (fake, scale), allow_unused=True)
    assert fake_gradient[:, :1].abs().sum() > 0 and fake_gradient[:, 1:].abs().sum() == 0
    assert scale_gradient is None or scale_gradient.abs().sum() == 0


def test_ssim_over_structured_windows_ignores_grain_in_flat_windows_and_keeps_preferring_detail():
    """With ``min_target_std`` only windows where the target varies count: grain on a flat half changes nothing."""
    torch.manual_seed(2)
    stripes = 0.5 + 0.2 * torch.sign(torch.sin(torch.arange(64) * 2 * np.pi / 8)).view(1, 1, 1, 64).expand(1, 1, 64, 64)
    target = stripes.clone()
    target[..., 32:] = 0.5  # the right half flat
    reading = target + 0.05 * torch.randn(1, 1, 64, 64)
    smooth_flat = reading.clone()
    smooth_flat[..., 38:] = 0.5  # beyond the reach of the 7-px windows that hold a stripe
    assert structural_similarity(smooth_flat, target) > structural_similarity(reading, target) + 0.1
    masked = [structural_similarity(r, target, min_target_std=0.03) for r in (reading, smooth_flat)]
    assert abs(float(masked[0] - masked[1])) < 1e-6  # the flat windows do not count
    blurred = gaussian_blur(target, 3.0)
    assert structural_similarity(reading, target, min_target_std=0.03) > structural_similarity(blurred, target, min_target_std=0.03)
    flat = torch.full((1, 1, 16, 16), 0.5, requires_grad=True)
    none = structural_similarity(flat + 0.1 * torch.randn(1, 1, 16, 16), torch.full((1, 1, 16, 16), 0.5), min_target_std=0.03)
    assert float(none) == 1.0 and not none.requires_grad
    torch.testing.assert_close(structural_similarity(reading, stripes, min_target_std=1e-4), structural_similarity(reading, stripes))


def test_pooled_ssim_scores_both_maps_averaged_over_the_pool():
    torch.manual_seed(3)
    target, fake = torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32)
    module = Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, ssim_weight=1.0, ssim_pool_px=2)
    _, parts = module.reconstruction_loss(fake, None, target)
    pooled = structural_similarity(torch.nn.functional.avg_pool2d(fake[:, :1], 2), torch.nn.functional.avg_pool2d(target[:, :1], 2))
    torch.testing.assert_close(parts["l_ssim"], pooled)
    assert abs(float(pooled - structural_similarity(fake[:, :1], target[:, :1]))) > 1e-3


def test_ssim_limited_to_regular_patterns_ignores_white_noise_items():
    """``ssim_max_b``: an item labelled white noise (b* 0) does not count; one labelled blue noise (b* -52) does."""
    torch.manual_seed(4)
    target = torch.rand(2, 3, 32, 32)
    target[:, 1] = 128 / 255.0
    target[0, 2], target[1, 2] = 128 / 255.0, 76 / 255.0  # b* 0 (white noise), -52 (blue noise)
    module = Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, ssim_weight=1.0, ssim_max_b=-20.0)
    fake = torch.rand(2, 3, 32, 32)
    other = fake.clone()
    other[0, 0] = torch.rand(32, 32)  # a different reading of the white-noise item only
    ssims = [module.reconstruction_loss(x, None, target)[1]["l_ssim"] for x in (fake, other)]
    torch.testing.assert_close(ssims[0], ssims[1])
    torch.testing.assert_close(ssims[0], structural_similarity(fake[1:, :1], target[1:, :1]))
