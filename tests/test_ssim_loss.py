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
