"""The conditional GAN as a LightningModule (SPEC §2.4, supplemental §1.4).

Manual optimisation, one discriminator and one generator step per batch:

* discriminator: ``(GAN(D(x, y), real) + GAN(D(x, G(x)), fake)) / 2``;
* generator: ``L1(G(x), y) + adversarial_weight * GAN(D(x, G(x)), real)``
  (paper: weight 0.001); with ``l_scale=True`` the generator also predicts the
  Laplace scale b of L (:meth:`~patternshop_nn.networks.DualBranchUNet.forward_with_scale`)
  and L's term of the L1 becomes ``l_nll_weight`` times the Laplace negative
  log-likelihood ``|y - mu| / b + log b`` (a, b keep their L1; the mean over
  the three channels as before). The weight multiplies the whole NLL, so its
  minimum stays at ``b = |y - mu|``; it sets how hard the shared encoder is
  pulled by L against a, b (``|y - mu| / b`` is about ``1 / b`` times L's L1);
  that ``1 / b`` also weighs the mean's error least where the network is least
  sure (textures, detail): ``l_mean_l1=True`` teaches the mean by L's plain L1
  (weight 1, as without the head) and the scale by the NLL of the mean
  detached (``l_nll_weight`` times it), so each pixel's error counts alike
  (the "beta-NLL" observation of Seitzer et al. 2022, for a Laplace);
  the scale head's parameters learn at ``l_scale_lr`` (a new head on a
  fine-tuned network: at the network's rate it stays nearly flat for
  hundreds of steps); ``blurred_l1_weight`` > 0 adds that weight times the L1
  between L/100 and its target both blurred by a Gaussian of
  ``blurred_l1_sigma_px`` pixels (:func:`~patternshop_nn.networks.blurred_l1`):
  density error a few point spacings wide, which the per-pixel terms let the
  network trade for a soft mean where its input is noisy; ``ssim_weight`` > 0
  adds that weight times ``1 - SSIM`` of L/100 against its target
  (:func:`~patternshop_nn.networks.structural_similarity`, scikit-image's
  defaults): the per-pixel terms' best answer where the points cannot pin a
  texture down is its local mean, a blur; SSIM also scores the local contrast
  and structure, so a map keeps the detail the points do carry;
  ``ssim_min_target_std`` > 0 scores SSIM only in the windows whose target
  varies by more than that (L/100 units), leaving flat windows to the
  per-pixel terms (in a flat window SSIM punishes any grain); ``ssim_pool_px``
  > 1 scores it on both maps averaged over that many pixels square, nearer
  the scale the figures score at (a 20,000-point map's pixel is 2-5 raster px);
  ``ssim_max_b`` counts only windows whose target b* is at most that: regular
  patterns (blue noise, lattices: b* < 0), whose points pin the density about
  one spacing wide, where white noise (b* 0) cannot tell texture from grain;
  ``full_res_channels`` > 0 adds a path at the raster's full resolution to
  the L logit (:class:`~patternshop_nn.networks.DualBranchUNet`; it starts at
  zero and learns at ``full_res_lr``, as the scale head at ``l_scale_lr``);
  ``full_res_stride`` k > 1 runs that path on the raster's k x k blocks
  (space to depth) at about 1/k**2 of its cost;
* Adam (lr 1e-4, betas (0.5, 0.999)) for both; ``lr_policy="step"``: the
  learning rates halve every ``lr_halving_epochs`` epochs (paper: 100);
  ``"linear"``: pix2pix's policy, constant for ``lr_constant_epochs`` epochs,
  then decaying linearly to 0 over ``lr_decay_epochs`` epochs (for a
  fine-tuning stage that ends when validation has settled).

Validation logs ``val/density_mae`` and ``val/latent_mae`` (see
:mod:`patternshop_nn.baselines`) and writes a PNG of a few predictions per
epoch into the logger's folder.
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from patternshop_nn.baselines import inked
from patternshop_nn.networks import (DualBranchUNet, GANLoss, PatchDiscriminator, blurred_l1, init_weights, laplace_nll,
                                     structural_similarity)
from synthesis.atomic import atomic_path

LR_POLICIES = ("step", "linear")
SSIM_WINDOW_PX = 7  # the SSIM term's window (scikit-image's default, as the figures score)


class Pix2PixModule(L.LightningModule):
    """Generator + conditional PatchGAN; ``generator`` maps (B, 1, S, S) rasters to (B, 3, S, S) maps in [0, 1]."""

    def __init__(self, levels: int = 6, base_channels: int = 12, max_channels: int = 96, dropout: float = 0.0,
                 disc_channels: int = 16, disc_layers: int = 3, gan_mode: str = "vanilla", adversarial_weight: float = 0.001,
                 lr: float = 1e-4, betas: tuple[float, float] = (0.5, 0.999), lr_halving_epochs: int = 100,
                 sample_images: int = 4, upsample: str = "transposed", lr_policy: str = "step", lr_constant_epochs: int = 0,
                 lr_decay_epochs: int = 20, l_scale: bool = False, l_nll_weight: float = 1.0, l_scale_lr: float = 1e-3,
                 blurred_l1_weight: float = 0.0, blurred_l1_sigma_px: float = 4.0, ssim_weight: float = 0.0,
                 ssim_min_target_std: float = 0.0, ssim_pool_px: int = 1, ssim_max_b: float | None = None,
                 full_res_channels: int = 0, full_res_lr: float = 1e-3, full_res_stride: int = 1,
                 correlation_encoder: bool = False, correlation_shared_levels: int = 0,
                 correlation_stride: int = 1, l_mean_l1: bool = False) -> None:
        super().__init__()
        if lr_policy not in LR_POLICIES:
            raise ValueError(f"unknown lr_policy {lr_policy!r}; choose one of {', '.join(LR_POLICIES)}")
        self.save_hyperparameters()
        self.automatic_optimization = False
        # upsample's default, "transposed", rebuilds checkpoints whose hparams predate the option;
        # conf/model/pix2pix.yaml (and the shipped model) use resize-convolution ("nearest").
        self.generator = DualBranchUNet(1, levels, base_channels, max_channels, dropout, upsample, l_scale, full_res_channels,
                                        full_res_stride, correlation_encoder, correlation_shared_levels, correlation_stride)
        self.discriminator = PatchDiscriminator(4, disc_channels, disc_layers)
        init_weights(self.generator)
        if full_res_channels > 0:
            self.generator.zero_refinement()
        init_weights(self.discriminator)
        self.gan_loss = GANLoss(gan_mode)
        self.l1 = nn.L1Loss()

    def forward(self, raster: torch.Tensor) -> torch.Tensor:
        return self.generator(raster)

    def _generate(self, raster: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(map (B, 3, S, S), Laplace scale of L (B, 1, S, S) or None without the head)."""
        if self.generator.l_scale:
            return self.generator.forward_with_scale(raster)
        return self.generator(raster), None

    def reconstruction_loss(self, fake: torch.Tensor, scale: torch.Tensor | None, target: torch.Tensor) -> tuple[torch.Tensor, dict]:
        """The generator's non-adversarial loss (L1, or L's Laplace NLL and a, b's L1; plus the weighted blurred L1 of L
        and the weighted 1 - SSIM of L;
        module docstring) and its parts to log."""
        l1 = self.l1(fake, target)
        if scale is None:
            loss, parts = l1, {"l1": l1}
        else:
            mean_l1 = self.hparams.get("l_mean_l1", False)  # the mean from its own L1, the scale from the NLL of it detached
            mean = fake[:, :1].detach() if mean_l1 else fake[:, :1]
            nll = laplace_nll(target[:, :1], mean, scale).mean()
            l_term = self.hparams.l_nll_weight * nll + ((fake[:, :1] - target[:, :1]).abs().mean() if mean_l1 else 0.0)
            loss, parts = (l_term + 2.0 * (fake[:, 1:] - target[:, 1:]).abs().mean()) / 3.0, {"l1": l1, "l_nll": nll}
        if self.hparams.blurred_l1_weight > 0:
            parts["l_blurred_l1"] = blurred_l1(fake[:, :1], target[:, :1], self.hparams.blurred_l1_sigma_px)
            loss = loss + self.hparams.blurred_l1_weight * parts["l_blurred_l1"]
        if self.hparams.get("ssim_weight", 0.0) > 0:
            parts["l_ssim"] = self._ssim_of_l(fake, target)
            loss = loss + self.hparams.ssim_weight * (1.0 - parts["l_ssim"])
        return loss, parts

    def _ssim_of_l(self, fake: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """SSIM of L against its target over the windows the ``ssim_*`` settings count (module docstring)."""
        hp = self.hparams
        pool = int(hp.get("ssim_pool_px", 1))
        fake, target = (F.avg_pool2d(x, pool) if pool > 1 else x for x in (fake, target))
        counted = None
        if hp.get("ssim_max_b") is not None:  # b* = 255 z - 128, z the target's third channel
            counted = 255.0 * F.avg_pool2d(target[:, 2:3], SSIM_WINDOW_PX, 1) - 128.0 <= hp.ssim_max_b
        return structural_similarity(fake[:, :1], target[:, :1], SSIM_WINDOW_PX,
                                     min_target_std=hp.get("ssim_min_target_std", 0.0), counted=counted)

    def configure_optimizers(self):  # noqa: ANN201 - Lightning's optimiser/scheduler lists
        hp = self.hparams
        head = list(self.generator.scale.parameters()) if self.generator.l_scale else []
        path = self.generator.full_res_parameters()
        rest = [p for p in self.generator.parameters() if all(p is not q for q in head + path)]
        groups = [{"params": rest}] + ([{"params": head, "lr": hp.get("l_scale_lr", hp.lr)}] if head else [])
        groups += [{"params": path, "lr": hp.get("full_res_lr", hp.lr)}] if path else []
        optimizers = [torch.optim.Adam(groups, lr=hp.lr, betas=tuple(hp.betas)),
                      torch.optim.Adam(self.discriminator.parameters(), lr=hp.lr, betas=tuple(hp.betas))]
        return optimizers, [self._scheduler(opt) for opt in optimizers]

    def _scheduler(self, optimizer: torch.optim.Optimizer) -> torch.optim.lr_scheduler.LRScheduler:
        """The epoch-wise learning-rate schedule of ``lr_policy`` (see module docstring)."""
        hp = self.hparams
        if hp.get("lr_policy", "step") == "step":
            return torch.optim.lr_scheduler.StepLR(optimizer, step_size=hp.lr_halving_epochs, gamma=0.5)
        constant, decay = int(hp.lr_constant_epochs), max(1, int(hp.lr_decay_epochs))
        return torch.optim.lr_scheduler.LambdaLR(optimizer, lambda epoch: min(1.0, max(0.0, 1.0 - (epoch - constant) / decay)))

    def training_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_index: int) -> None:
        raster, target = batch
        opt_g, opt_d = self.optimizers()
        fake, scale = self._generate(raster)

        self.toggle_optimizer(opt_d)
        loss_d = 0.5 * (self.gan_loss(self.discriminator(raster, target), True)
                        + self.gan_loss(self.discriminator(raster, fake.detach()), False))
        opt_d.zero_grad(set_to_none=True)
        self.manual_backward(loss_d)
        opt_d.step()
        self.untoggle_optimizer(opt_d)

        self.toggle_optimizer(opt_g)
        loss_rec, parts = self.reconstruction_loss(fake, scale, target)
        loss_adv = self.gan_loss(self.discriminator(raster, fake), True)
        loss_g = loss_rec + self.hparams.adversarial_weight * loss_adv
        opt_g.zero_grad(set_to_none=True)
        self.manual_backward(loss_g)
        opt_g.step()
        self.untoggle_optimizer(opt_g)

        self.log_dict({**{f"train/{name}": value for name, value in parts.items()}, "train/adv": loss_adv, "train/d": loss_d},
                      prog_bar=True, on_step=True, on_epoch=True, batch_size=len(raster))

    def on_train_epoch_end(self) -> None:
        for scheduler in self.lr_schedulers():
            scheduler.step()

    def validation_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_index: int) -> None:
        raster, target = batch
        predicted, scale = self._generate(raster)
        density_error = (predicted[:, 0] - target[:, 0]).abs().mean()
        if scale is not None:  # calibration: a Laplace scale is the expected |error|, so the ratio should be about 1
            self.log_dict({"val/l_nll": laplace_nll(target[:, :1], predicted[:, :1], scale).mean(),
                           "val/l_scale_mean": scale.mean(),
                           "val/l_error_over_scale": ((predicted[:, :1] - target[:, :1]).abs() / scale).mean()},
                          batch_size=len(raster))
        latent_error = (predicted[:, 1:] - target[:, 1:]).abs().mean(dim=1)[inked(target[:, 0])]
        # batch sums weighted like the metrics' definitions (pixels; inked pixels for the latent)
        self.log("val/density_mae", density_error, batch_size=len(raster), prog_bar=True)
        if latent_error.numel():
            self.log("val/latent_mae", latent_error.mean(), batch_size=latent_error.numel(), prog_bar=True)
        self.log("val/l1", self.l1(predicted, target), batch_size=len(raster))
        if batch_index == 0 and self.hparams.sample_images:
            self._save_samples(raster, predicted, target)

    def on_validation_epoch_end(self) -> None:
        """Log the non-learned baselines measured on the same validation pairs (constant; for comparison)."""
        datamodule = getattr(self.trainer, "datamodule", None)
        baselines = getattr(datamodule, "baseline_metrics", None)
        if baselines and not self.trainer.sanity_checking:
            self.log_dict({"val/kde_density_mae": baselines["kde_density_mae"],
                           "val/baseline_latent_mae": baselines["baseline_latent_mae"]})

    def _save_samples(self, raster: torch.Tensor, predicted: torch.Tensor, target: torch.Tensor) -> None:
        """PNG rows of (raster | predicted map | true map) as sRGB, into ``<log dir>/samples/``."""
        logger = self.logger
        if logger is None or getattr(logger, "log_dir", None) is None or self.trainer.sanity_checking:
            return
        from PIL import Image

        from synthesis.labmap import LabMap

        def array(values: torch.Tensor) -> np.ndarray:  # float32: numpy has no bfloat16 (trainer.precision=bf16-mixed)
            return values.detach().float().cpu().numpy()

        def srgb(maps: torch.Tensor) -> np.ndarray:
            return LabMap.from_network(array(maps)).to_srgb()

        rows = []
        for k in range(min(self.hparams.sample_images, len(raster))):
            counts = array(raster[k, 0])
            points = 1.0 - np.repeat((counts / max(float(counts.max()), 1e-6))[..., None], 3, -1)
            rows.append(np.concatenate([points, srgb(predicted[k]), srgb(target[k])], axis=1))
        image = (np.concatenate(rows, axis=0) * 255).round().clip(0, 255).astype(np.uint8)
        path = Path(logger.log_dir) / "samples" / f"epoch{self.current_epoch:04d}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            Image.fromarray(image).save(tmp, format="PNG")


def save_module_checkpoint(module: Pix2PixModule, path: str | Path, **record: object) -> Path:
    """Write ``module`` as a checkpoint ``train.py init_from=``, ``patternshop export`` and ``load_from_checkpoint`` read
    (its state dict, hyper-parameters and Lightning's version; ``record``: more keys saying where it came from),
    atomically, creating the folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save({"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams),
                    "pytorch-lightning_version": L.__version__, **record}, tmp)
    return path
