"""The points-to-map network (SPEC §2.4, supplemental §1.4): generator, discriminator, GAN loss.

Shapes and ranges (B = batch, S = raster size, a multiple of ``2**levels``):

* generator input: (B, 1, S, S) point raster in [0, 1] (:func:`synthesis.raster.point_raster`);
* generator output: (B, 3, S, S) in [0, 1]: channel 0 is L/100 (``1 - density``),
  channels 1-2 the latent z of the correlation (``a, b = 255 z - 128``);
* with ``l_scale=True``, :meth:`DualBranchUNet.forward_with_scale` also gives (B, 1, S, S) > 0: the
  Laplace scale ``b`` of channel 0 (the expected absolute error of L/100, i.e. of the density, in 0..1 units),
  from its own head (``scale``: like a decoder's head, on the density decoder's last features; softplus +
  :data:`L_SCALE_MIN`), so the map's layers are those of a generator without it; trained by the Laplace
  negative log-likelihood :func:`laplace_nll`;
* discriminator input: raster and map concatenated, (B, 4, S, S); output: (B, 1, S/8 - 2, S/8 - 2)
  patch logits (30 x 30 at S = 256; 3 strided layers, a 70 x 70 receptive field as pix2pix's PatchGAN).

The generator is a pix2pix U-Net with one encoder and **two decoders**, one
for density (1 channel) and one for correlation (2 channels), each with skip
connections from the shared encoder; their outputs are concatenated and passed
through a sigmoid. Widths double from ``base_channels`` per level up to
``max_channels``. With ``correlation_encoder=True`` the correlation decoder reads
an encoder of its own (:class:`Encoder`, the same widths) instead, so its a, b
can learn without moving L (``python -m patternshop_nn.tune_encoder``). With
``correlation_stride`` > 1 the correlation decoder stops at that fraction of the
raster's side and up-samples its a, b bilinearly (a cheaper pass; a, b are smooth).

Up-sampling (``upsample``):

* ``"transposed"``: pix2pix's 4x4 stride-2 transposed convolutions. Each output
  pixel gets other kernel taps by its parity, so every level can print a
  2-pixel checkerboard and the stack of them a lattice of period ``2**levels``
  (64 px), seen as marks on a 64-px grid in empty areas (a model trained with
  it, patternshop-procedural-v1, locked 94 % of its L and a,b variance to that
  grid's phase; ``docs/history/model-v5.md``).
* ``"nearest"`` or ``"bilinear"``: resize-convolution (Odena, Dumoulin and Olah,
  "Deconvolution and checkerboard artifacts", Distill 2016): up-sample by 2,
  then a 3x3 convolution. Every output pixel sees the same kernel, so a
  constant input gives a constant output away from the borders. ``"nearest"``
  is the configured default (``conf/model/pix2pix.yaml``) and the shipped
  model's choice.

For inference, :func:`fuse_upsampling` rewrites every nearest up-sampling and
its 3x3 convolution as :class:`NearestUpConv`, the same function computed at
the lower resolution (2.25 times fewer multiply-adds); the exporter applies it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

UPSAMPLING = ("transposed", "nearest", "bilinear")
L_SCALE_MIN = 1e-3  # smallest Laplace scale of L/100 the head predicts (a tenth of an L unit)


def laplace_nll(target: torch.Tensor, mean: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Per-pixel Laplace negative log-likelihood ``|target - mean| / scale + log scale`` (without log 2); for a fixed
    error it is smallest at ``scale = |target - mean|``. Shapes broadcast; scale > 0."""
    return (target - mean).abs() / scale + torch.log(scale)


def gaussian_blur(maps: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """Each channel of (B, C, H, W) ``maps`` blurred by a Gaussian of ``sigma_px`` pixels: a fixed depthwise
    separable convolution, truncated at 3 sigma, edges replicated (H, W > 3 sigma); same shape and units."""
    radius = max(1, round(3.0 * sigma_px))
    offsets = torch.arange(-radius, radius + 1, dtype=maps.dtype, device=maps.device)
    taps = torch.exp(-0.5 * (offsets / sigma_px) ** 2)
    taps = taps / taps.sum()
    channels = maps.shape[1]
    padded = F.pad(maps, (radius, radius, radius, radius), mode="replicate")
    rows = F.conv2d(padded, taps.view(1, 1, 1, -1).expand(channels, 1, 1, -1), groups=channels)
    return F.conv2d(rows, taps.view(1, 1, -1, 1).expand(channels, 1, -1, 1), groups=channels)


def blurred_l1(predicted: torch.Tensor, target: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """Mean ``|G * predicted - G * target|`` over (B, C, H, W), G a Gaussian of ``sigma_px`` pixels
    (:func:`gaussian_blur`; linear, so the difference is blurred once): the error a few point spacings wide, in the
    maps' units; a scalar >= 0."""
    return gaussian_blur(predicted - target, sigma_px).abs().mean()


def structural_similarity(predicted: torch.Tensor, target: torch.Tensor, window_px: int = 7,
                          data_range: float = 1.0, min_target_std: float = 0.0,
                          counted: torch.Tensor | None = None) -> torch.Tensor:
    """Mean SSIM of (B, C, H, W) ``predicted`` against ``target`` (values within ``data_range``), as scikit-image's
    ``structural_similarity`` computes it by default: a uniform ``window_px`` square window, sample covariances,
    K1 0.01, K2 0.03, averaged over the windows that lie wholly inside (H, W >= ``window_px``); a scalar <= 1,
    differentiable. The frozen and development figures score L with that function (``patternshop_nn.ood``).

    ``min_target_std`` > 0 averages only over the windows where the target's standard deviation exceeds it (in the
    maps' units): the windows with structure to keep. In a flat window SSIM's structure term C2 / (σ² + C2) punishes
    any grain, and most windows of training maps are flat. ``counted``, a boolean (B, C, H - window_px + 1,
    W - window_px + 1) over the windows (e.g. from ``F.avg_pool2d(x, window_px, 1)`` of another map), restricts the
    average further. With no window left the result is 1, with no gradient."""
    count = window_px * window_px
    sample = count / (count - 1.0)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mean_p, mean_t = F.avg_pool2d(predicted, window_px, 1), F.avg_pool2d(target, window_px, 1)
    var_p = sample * (F.avg_pool2d(predicted * predicted, window_px, 1) - mean_p * mean_p)
    var_t = sample * (F.avg_pool2d(target * target, window_px, 1) - mean_t * mean_t)
    cov = sample * (F.avg_pool2d(predicted * target, window_px, 1) - mean_p * mean_t)
    ssim = ((2 * mean_p * mean_t + c1) * (2 * cov + c2)) / ((mean_p ** 2 + mean_t ** 2 + c1) * (var_p + var_t + c2))
    if min_target_std <= 0 and counted is None:
        return ssim.mean()
    kept = counted if counted is not None else torch.ones_like(var_t, dtype=torch.bool)
    if min_target_std > 0:
        kept = kept & (var_t > min_target_std ** 2)
    return ssim[kept].mean() if bool(kept.any()) else ssim.new_ones(())


def _down(in_channels: int, out_channels: int, norm: bool) -> nn.Sequential:
    """Encoder level: LeakyReLU, 4x4 stride-2 convolution (halves the size), batch norm."""
    layers: list[nn.Module] = [nn.LeakyReLU(0.2), nn.Conv2d(in_channels, out_channels, 4, 2, 1, bias=not norm)]
    if norm:
        layers.append(nn.BatchNorm2d(out_channels))
    return nn.Sequential(*layers)


def _double(in_channels: int, out_channels: int, upsample: str, bias: bool) -> list[nn.Module]:
    """Layers that double the size: a transposed 4x4 stride-2 convolution, or a resize then a 3x3 convolution."""
    if upsample == "transposed":
        return [nn.ConvTranspose2d(in_channels, out_channels, 4, 2, 1, bias=bias)]
    align = {"align_corners": False} if upsample == "bilinear" else {}
    return [nn.Upsample(scale_factor=2, mode=upsample, **align), nn.Conv2d(in_channels, out_channels, 3, 1, 1, bias=bias)]


def _up(in_channels: int, out_channels: int, dropout: float, upsample: str) -> nn.Sequential:
    """Decoder level: ReLU, doubling (:func:`_double`), batch norm, dropout."""
    layers: list[nn.Module] = [nn.ReLU(), *_double(in_channels, out_channels, upsample, bias=False), nn.BatchNorm2d(out_channels)]
    if dropout > 0:
        layers.append(nn.Dropout(dropout))
    return nn.Sequential(*layers)


class Encoder(nn.Module):
    """A U-Net encoder: ``first`` (a 4x4 stride-2 convolution) then ``downs`` (:func:`_down`) -> features, first level first.

    ``shared_levels`` > 0: the first that many levels are another encoder's (given to :meth:`forward`); this one has
    no ``first`` and an ``nn.Identity`` in their ``downs`` places, so its layers keep their levels' names.
    """

    def __init__(self, in_channels: int, widths: list[int], shared_levels: int = 0) -> None:
        super().__init__()
        if not 0 <= shared_levels < len(widths):
            raise ValueError(f"shared_levels must be in 0 .. {len(widths) - 1}, got {shared_levels}")
        self.shared_levels = shared_levels
        self.first = nn.Conv2d(in_channels, widths[0], 4, 2, 1) if shared_levels == 0 else None
        self.downs = nn.ModuleList(_down(widths[k - 1], widths[k], norm=k < len(widths) - 1) if k >= shared_levels else nn.Identity()
                                   for k in range(1, len(widths)))

    def forward(self, raster: torch.Tensor, shared: list[torch.Tensor] | None = None) -> list[torch.Tensor]:
        """Features of ``raster`` (B, C, S, S), each level half the last's side; ``shared``: the other encoder's
        features (at least ``shared_levels`` of them, first first), needed when ``shared_levels`` > 0."""
        if self.first is not None:
            features = [self.first(raster)]
        elif shared is None or len(shared) < self.shared_levels:
            raise ValueError(f"this encoder starts after {self.shared_levels} shared levels: pass their features")
        else:
            features = list(shared[: self.shared_levels])
        for down in self.downs[len(features) - 1 :]:
            features.append(down(features[-1]))
        return features


def decoder_steps(stride: int, levels: int) -> int:
    """t for a decoder ``stride`` = 2**t of a U-Net of ``levels`` levels (0 <= t <= levels - 1); ValueError otherwise."""
    steps = stride.bit_length() - 1
    if stride < 1 or stride != 2**steps or steps > levels - 1:
        raise ValueError(f"stride must be a power of 2 up to {2 ** (levels - 1)}, got {stride}")
    return steps


class Decoder(nn.Module):
    """One U-Net decoder branch over the encoder's features (deepest first) -> (B, out_channels, S, S) logits.

    ``stride`` = 2**t > 1: the branch stops t levels early, at S / stride, where its head (ReLU and a 3x3
    convolution) reads the last up level with that level's skip; the logits are up-sampled bilinearly to S. A cheap
    branch for outputs smooth at that scale (a, b: ``DualBranchUNet.coarse_correlation_decoder``).
    """

    def __init__(self, widths: list[int], out_channels: int, dropout: float, upsample: str = "transposed",
                 stride: int = 1) -> None:
        super().__init__()
        # widths[k] = channels of encoder level k (k = 0 is the first, at S/2).
        levels = len(widths)
        steps = decoder_steps(stride, levels)  # t
        self.stride = stride
        self.skip_level = max(0, steps - 1)  # the level whose skip the head reads
        ups = [_up(widths[-1], widths[-2], dropout, upsample)]
        for k in range(levels - 2, self.skip_level, -1):  # input: previous up output concatenated with the skip of level k
            ups.append(_up(2 * widths[k], widths[k - 1], dropout if k >= levels - 3 else 0.0, upsample))
        self.ups = nn.ModuleList(ups)
        if stride == 1:
            self.head = nn.Sequential(nn.ReLU(), *_double(2 * widths[0], out_channels, upsample, bias=True))
        else:
            self.head = nn.Sequential(nn.ReLU(), nn.Conv2d(2 * widths[self.skip_level], out_channels, 3, 1, 1))

    def last_features(self, features: list[torch.Tensor]) -> torch.Tensor:
        """(B, 2 widths[l], S/2^(l+1), S/2^(l+1)): what the head reads (the last up level's output and the skip of
        level l, :attr:`skip_level`; l = 0 for ``stride`` 1 and 2)."""
        x = self.ups[0](features[-1])
        for up, skip in zip(self.ups[1:], reversed(features[self.skip_level + 1 : -1]), strict=True):
            x = up(torch.cat([x, skip], 1))
        return torch.cat([x, features[self.skip_level]], 1)

    def forward(self, features: list[torch.Tensor]) -> torch.Tensor:
        logits = self.head(self.last_features(features))
        if self.stride == 1:
            return logits
        return F.interpolate(logits, scale_factor=self.stride, mode="bilinear", align_corners=False)


class DualBranchUNet(nn.Module):
    """U-Net generator with a density and a correlation decoder (see module docstring).

    Args:
        levels: down-/up-sampling levels (paper: 6); the raster side must be a multiple of ``2**levels``.
        base_channels: channels after the first level; doubled per level up to ``max_channels``.
        dropout: dropout in the three deepest decoder levels (pix2pix's noise), 0 to disable.
        upsample: the decoders' up-sampling, one of :data:`UPSAMPLING` (see module docstring). The
            argument's default, "transposed", rebuilds checkpoints whose recorded hyperparameters
            do not name it; the config (and the shipped model) use "nearest".
        l_scale: a head for the Laplace scale of L on the density decoder's last features
            (:meth:`forward_with_scale`); :meth:`forward` gives the map alone either way.
        full_res_channels: > 0 adds a path at the raster's full resolution (the U-Net's finest features are at half
            of it, behind one stride-2 convolution of the raw counts): two 3 x 3 convolutions of the raster with this
            many channels, read with the density decoder's L logit by a 3 x 3 convolution whose output is added to
            that logit. That convolution starts at zero, so a generator loaded without the path is unchanged.
        full_res_stride: the path reads the raster in ``k x k`` blocks (space to depth): its convolutions run at
            ``1/k`` of the raster's resolution on ``k**2`` channels of counts, and its last one gives ``k**2``
            corrections per block, put back pixel by pixel (pixel shuffle), so the correction keeps the full
            resolution at about ``1/k**2`` of the cost (1: every convolution at full resolution).
        correlation_encoder: the correlation decoder reads an encoder of its own (``correlation_encoder``, an
            :class:`Encoder` of the same widths) instead of the density decoder's: a, b can learn what the shared
            features hide while L and its scale stay as they are (:meth:`own_correlation_encoder` starts it as a copy).
        correlation_shared_levels: with ``correlation_encoder``, the first this many levels stay the shared encoder's
            (the own one starts from their features): the own encoder costs less (0: all its own).
        correlation_stride: the correlation decoder stops at S / this (a power of 2) and up-samples its logits
            bilinearly (:class:`Decoder`); 1: it runs to S as the density decoder does.
    """

    def __init__(self, in_channels: int = 1, levels: int = 6, base_channels: int = 16, max_channels: int = 128,
                 dropout: float = 0.0, upsample: str = "transposed", l_scale: bool = False,
                 full_res_channels: int = 0, full_res_stride: int = 1, correlation_encoder: bool = False,
                 correlation_shared_levels: int = 0, correlation_stride: int = 1) -> None:
        super().__init__()
        if levels < 2:
            raise ValueError(f"levels must be at least 2, got {levels}")
        if full_res_stride < 1 or 2**levels % full_res_stride:
            raise ValueError(f"full_res_stride must divide {2**levels} (the raster side's factor), got {full_res_stride}")
        if upsample not in UPSAMPLING:
            raise ValueError(f"unknown up-sampling {upsample!r}; choose one of {', '.join(UPSAMPLING)}")
        widths = [min(base_channels * 2**k, max_channels) for k in range(levels)]
        self.levels = levels
        self.upsample = upsample
        self.l_scale = l_scale
        self.first = nn.Conv2d(in_channels, widths[0], 4, 2, 1)
        self.downs = nn.ModuleList(_down(widths[k - 1], widths[k], norm=k < levels - 1) for k in range(1, levels))
        self.widths = widths  # channels per encoder level, first first
        self.density = Decoder(widths, 1, dropout, upsample)
        self.correlation = Decoder(widths, 2, dropout, upsample, correlation_stride)
        self.correlation_encoder = Encoder(in_channels, widths, correlation_shared_levels) if correlation_encoder else None
        if l_scale:
            self.scale = nn.Sequential(nn.ReLU(), *_double(2 * widths[0], 1, upsample, bias=True))
        self.full_res_channels = full_res_channels
        self.full_res_stride = full_res_stride
        if full_res_channels > 0:
            blocks = full_res_stride**2  # raster pixels per block: the path's input and output channels
            self.full_res = nn.Sequential(nn.Conv2d(in_channels * blocks, full_res_channels, 3, 1, 1), nn.LeakyReLU(0.2),
                                          nn.Conv2d(full_res_channels, full_res_channels, 3, 1, 1), nn.LeakyReLU(0.2))
            self.refine = nn.Conv2d(full_res_channels + blocks, blocks, 3, 1, 1)
            self.zero_refinement()

    FULL_RES_MODULES = ("full_res", "refine")  # the full-resolution path's submodules (names in the state dict)

    def full_res_parameters(self) -> list[nn.Parameter]:
        """The full-resolution path's parameters (none without the path)."""
        return [p for name, p in self.named_parameters() if name.startswith(self.FULL_RES_MODULES)]

    def zero_refinement(self) -> None:
        """Set the full-resolution path's last convolution to zero: the L logit is the decoder's alone."""
        nn.init.zeros_(self.refine.weight)
        nn.init.zeros_(self.refine.bias)

    def _refined(self, raster: torch.Tensor, l_logit: torch.Tensor) -> torch.Tensor:
        """(B, 1, S, S) the L logit plus the full-resolution path's correction (itself without the path)."""
        if self.full_res_channels <= 0:
            return l_logit
        k = self.full_res_stride
        if k == 1:  # the graph exported before strides existed, without no-op shuffles
            return l_logit + self.refine(torch.cat([self.full_res(raster), l_logit], 1))
        blocks = torch.cat([self.full_res(F.pixel_unshuffle(raster, k)), F.pixel_unshuffle(l_logit, k)], 1)
        return l_logit + F.pixel_shuffle(self.refine(blocks), k)

    def _encode(self, raster: torch.Tensor, levels: int | None = None) -> list[torch.Tensor]:
        """The encoder's features, first level first (the first ``levels`` of them; None: all)."""
        side = raster.shape[-1]
        if raster.shape[-2] != side or side % 2**self.levels:
            raise ValueError(f"raster must be square with a side divisible by {2**self.levels}, got {tuple(raster.shape[-2:])}")
        features = [self.first(raster)]
        for down in self.downs[: (self.levels if levels is None else levels) - 1]:
            features.append(down(features[-1]))
        return features

    def own_correlation_encoder(self, shared_levels: int = 0) -> None:
        """Give the correlation decoder an encoder of its own, a copy of the shared one from level ``shared_levels``
        on (the levels before stay shared); the function is unchanged. A generator that has one keeps it."""
        if self.correlation_encoder is None:
            self.correlation_encoder = Encoder(self.first.in_channels, self.widths, shared_levels)
            if self.correlation_encoder.first is not None:
                self.correlation_encoder.first.load_state_dict(self.first.state_dict())
            for own, shared in zip(self.correlation_encoder.downs, self.downs, strict=True):
                if not isinstance(own, nn.Identity):  # a shared level's place
                    own.load_state_dict(shared.state_dict())
            self.correlation_encoder.train(self.training)  # a new module trains; it takes the generator's mode

    def coarse_correlation_decoder(self, stride: int) -> None:
        """Stop the correlation decoder at S / ``stride``: its levels down to there are kept (weights and all), its
        head is new (ReLU and a 3x3 convolution, initialised as :func:`init_weights` does, bias 0) and its logits are
        up-sampled bilinearly. L is unchanged; a, b start near 0 and must be trained (``tune_encoder
        --correlation-stride``). A decoder already at ``stride`` is kept."""
        old = self.correlation
        if old.stride == stride:
            return
        if old.stride != 1:
            raise ValueError(f"the correlation decoder already stops at S/{old.stride}; it can be coarsened only from S")
        new = Decoder(self.widths, 2, 0.0, self.upsample, stride)
        new.ups = old.ups[: len(new.ups)]  # the trained levels, their dropout included
        init_weights(new.head)
        self.correlation = new.train(self.training)

    def correlation_features(self, raster: torch.Tensor, features: list[torch.Tensor] | None = None) -> list[torch.Tensor]:
        """The features the correlation decoder reads: its own encoder's, else the shared one's (first level first);
        ``features``: the shared encoder's, when computed."""
        own = self.correlation_encoder
        if own is None:
            return features if features is not None else self._encode(raster)
        shared = None
        if own.shared_levels:
            shared = features if features is not None else self._encode(raster, own.shared_levels)
        return own(raster, shared)

    def correlation_logits(self, raster: torch.Tensor, features: list[torch.Tensor] | None = None) -> torch.Tensor:
        """(B, 2, S, S) the a, b logits of a raster (B, 1, S, S); ``features``: the shared encoder's, when computed."""
        return self.correlation(self.correlation_features(raster, features))

    def forward(self, raster: torch.Tensor) -> torch.Tensor:
        """(B, 1, S, S) raster in [0, 1] -> (B, 3, S, S) map in [0, 1] (L/100, z_a, z_b)."""
        features = self._encode(raster)
        return torch.sigmoid(torch.cat([self._refined(raster, self.density(features)), self.correlation_logits(raster, features)], 1))

    def forward_with_scale(self, raster: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(map (B, 3, S, S) as :meth:`forward`, Laplace scale of L/100 (B, 1, S, S) >= :data:`L_SCALE_MIN`); needs ``l_scale``."""
        if not self.l_scale:
            raise ValueError("this generator has no l_scale head (built with l_scale=False)")
        features = self._encode(raster)
        last = self.density.last_features(features)
        lab = torch.sigmoid(torch.cat([self._refined(raster, self.density.head(last)), self.correlation_logits(raster, features)], 1))
        return lab, F.softplus(self.scale(last)) + L_SCALE_MIN


class WithScale(nn.Module):
    """A generator with an ``l_scale`` head whose ``forward`` returns (map, l_scale): the exported graph's two outputs."""

    def __init__(self, generator: DualBranchUNet) -> None:
        super().__init__()
        self.generator = generator

    def forward(self, raster: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.generator.forward_with_scale(raster)


class NearestUpConv(nn.Module):
    """``Conv3x3(Upsample2x_nearest(x))`` (zero padding 1) computed on x: (B, Cin, h, w) -> (B, Cout, 2h, 2w).

    Output pixel ``(2i + a, 2j + b)`` sees only x's rows ``i - 1 + a .. i + a`` and columns ``j - 1 + b .. j + b``:
    up-sampled rows repeat x's, so the 3x3 taps fold into a 2x2 kernel per phase ``(a, b)``
    (rows: a = 0 takes ``W0 | W1 + W2``, a = 1 takes ``W0 + W1 | W2``; columns likewise). One 2x2
    convolution of the zero-padded x gives all four phases on an (h + 1, w + 1) grid, phase (a, b) starting
    at (a, b); a pixel shuffle interleaves them. 16 instead of 36 multiply-adds per input-output channel pair
    and input pixel; the result equals the reference to float rounding.
    """

    def __init__(self, conv: nn.Conv2d) -> None:
        super().__init__()
        if conv.kernel_size != (3, 3) or conv.stride != (1, 1) or conv.padding != (1, 1) or conv.dilation != (1, 1) or conv.groups != 1:
            raise ValueError(f"NearestUpConv needs a 3x3 convolution with stride 1 and padding 1, got {conv}")
        weight = conv.weight.detach()
        rows = [torch.stack([weight[:, :, 0], weight[:, :, 1] + weight[:, :, 2]], 2),  # (Cout, Cin, 2, 3) per row phase
                torch.stack([weight[:, :, 0] + weight[:, :, 1], weight[:, :, 2]], 2)]
        phases = []
        for row in rows:
            for cols in ([row[..., 0], row[..., 1] + row[..., 2]], [row[..., 0] + row[..., 1], row[..., 2]]):
                phases.append(torch.stack(cols, 3))  # (Cout, Cin, 2, 2)
        out_channels = weight.shape[0]
        # channel order (Cout, phase) as pixel_shuffle wants: channel c * 4 + 2 a + b
        self.register_buffer("weight", torch.stack(phases, 1).reshape(4 * out_channels, *weight.shape[1:2], 2, 2).contiguous())
        bias = conv.bias.detach() if conv.bias is not None else torch.zeros(out_channels)
        self.register_buffer("bias", bias.repeat_interleave(4).contiguous())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        grid = F.conv2d(x, self.weight, self.bias, padding=1)  # zero-padded: (B, 4 Cout, h + 1, w + 1)
        batch, channels = grid.shape[:2]
        grid = grid.reshape(batch, channels // 4, 4, h + 1, w + 1)
        phases = [grid.select(2, 2 * a + b).narrow(2, a, h).narrow(3, b, w) for a in (0, 1) for b in (0, 1)]
        return F.pixel_shuffle(torch.stack(phases, 2).reshape(batch, channels, h, w), 2)


def fuse_upsampling(generator: nn.Module) -> nn.Module:
    """The generator with every nearest ``Upsample`` + 3x3 ``Conv2d`` pair replaced by :class:`NearestUpConv` (in place).

    For inference and export; other layers (and bilinear or transposed up-sampling) are left as they are.
    """
    for module in generator.modules():
        if not isinstance(module, nn.Sequential):
            continue
        for k in range(len(module) - 1):
            first, second = module[k], module[k + 1]
            if isinstance(first, nn.Upsample) and first.mode == "nearest" and first.scale_factor in (2, 2.0) \
                    and isinstance(second, nn.Conv2d):
                module[k], module[k + 1] = NearestUpConv(second), nn.Identity()
    return generator


class PatchDiscriminator(nn.Module):
    """Conditional PatchGAN: (B, in_channels, S, S) -> (B, 1, S/8 - 2, S/8 - 2) real/fake logits per patch (layers=3).

    Three strided 4x4 convolutions (``base_channels`` doubling per layer), one
    stride-1 convolution and a 1-channel output convolution (pix2pix's
    ``n_layers=3`` discriminator).
    """

    def __init__(self, in_channels: int = 4, base_channels: int = 32, layers: int = 3) -> None:
        super().__init__()
        blocks: list[nn.Module] = [nn.Conv2d(in_channels, base_channels, 4, 2, 1), nn.LeakyReLU(0.2)]
        width = base_channels
        for k in range(1, layers + 1):
            out = base_channels * min(2**k, 8)
            stride = 2 if k < layers else 1
            blocks += [nn.Conv2d(width, out, 4, stride, 1, bias=False), nn.BatchNorm2d(out), nn.LeakyReLU(0.2)]
            width = out
        blocks.append(nn.Conv2d(width, 1, 4, 1, 1))
        self.net = nn.Sequential(*blocks)

    def forward(self, raster: torch.Tensor, lab: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([raster, lab], 1))


class GANLoss(nn.Module):
    """Adversarial loss on patch logits: ``vanilla`` (pix2pix's BCE) or ``lsgan`` (least squares)."""

    def __init__(self, mode: str = "vanilla") -> None:
        super().__init__()
        if mode not in ("vanilla", "lsgan"):
            raise ValueError(f"unknown GAN loss {mode!r}; choose vanilla or lsgan")
        self.loss = nn.BCEWithLogitsLoss() if mode == "vanilla" else nn.MSELoss()

    def forward(self, logits: torch.Tensor, real: bool) -> torch.Tensor:
        return self.loss(logits, torch.full_like(logits, 1.0 if real else 0.0))


def init_weights(module: nn.Module, gain: float = 0.02) -> None:
    """pix2pix initialisation: convolutions N(0, gain), batch-norm scales N(1, gain), biases 0."""
    for layer in module.modules():
        if isinstance(layer, nn.Conv2d | nn.ConvTranspose2d):
            nn.init.normal_(layer.weight, 0.0, gain)
            if layer.bias is not None:
                nn.init.zeros_(layer.bias)
        elif isinstance(layer, nn.BatchNorm2d):
            nn.init.normal_(layer.weight, 1.0, gain)
            nn.init.zeros_(layer.bias)
