"""Perceptual texture features of point patterns: Gram matrices of CNN activations.

A pattern is rasterised three times with Gaussian splats (std 0.015, 0.01 and
0.005 of a unit domain holding the corpus density of 1,024 points), each raster
goes through a CNN, and the Gram matrices of two layers with 64 and 128
channels are stacked: 3 x (64^2 + 128^2) = 61,440 values (paper §4, after
Gatys et al. 2016 and Tu et al. 2019). Dissimilarity is the L1 distance.

Two extractors:

* ``random-cnn`` (default, needs no download): a fixed-seed random multi-scale
  CNN — 64 zero-mean random filters of sizes 3, 5, 7 and 11 pixels, ReLU, 2x2
  average pooling (layer 1, 64 channels), then 128 dilated 3x3 random filters,
  ReLU, pooling (layer 2, 128 channels). Ustyuzhaninov et al. (2017, "What does
  it take to generate natural textures?") showed that Gram matrices of a single
  layer of random multi-scale filters capture texture statistics about as well
  as a trained VGG for texture synthesis; point patterns are stationary
  textures whose relevant scales (1-3 point spacings = 8-24 px here) are covered
  by the filter sizes and the second, dilated layer.
* ``vgg16``: VGG-16's first two blocks (pool1: 64 channels, pool2: 128), layers
  defined here, weights loaded from a local torchvision-format file
  (``vgg16-397923af.pth`` or any state dict with ``features.{0,2,5,7}.*``).

Query patterns of any density are brought to the corpus density by rescaling
their coordinates; large ones are cropped to a central window of at most
:data:`WINDOW_POINTS` points' worth of area. Both corpus and query feature maps
lose a border margin before the Gram matrices, so zero padding and missing
splats outside a window do not bias them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from synthesis.errors import PatternshopError

FEATURES_VERSION = 1  # bump when the rasteriser or a network changes: cached corpora are then rebuilt
SPLAT_SIGMAS = (0.015, 0.01, 0.005)  # in units of a corpus domain side
CORPUS_POINTS = 1024  # points per unit area at which features are taken
PIXELS_PER_UNIT = 256
WINDOW_POINTS = 2048  # query windows hold at most this many points' worth of area
MARGIN_PIXELS = 28  # border dropped from feature maps (splat radius + receptive field)
LAYER_CHANNELS = (64, 128)
FEATURE_SIZE = len(SPLAT_SIGMAS) * sum(c * c for c in LAYER_CHANNELS)
_IMAGENET_MEAN = (0.485, 0.456, 0.406)
_IMAGENET_STD = (0.229, 0.224, 0.225)


def splat_raster(
    points: np.ndarray, size: tuple[int, int], sigma: float, pixels_per_unit: float, periodic: bool
) -> np.ndarray:
    """Sum of unit-peak Gaussian splats, (H, W) float32.

    Args:
        points: (n, 2) positions (x right, y down) in domain units.
        size: (H, W) raster size; pixel (i, j) is centred at ((j + .5), (i + .5)) / pixels_per_unit.
        sigma: splat standard deviation in domain units.
        periodic: wrap distances around the raster (a torus of the raster's extent).
    """
    height, width = size
    sigma_px = sigma * pixels_per_unit
    px = np.asarray(points, np.float64) * pixels_per_unit

    def axis_weights(coord: np.ndarray, length: int) -> np.ndarray:
        offset = (np.arange(length) + 0.5)[None, :] - coord[:, None]
        if periodic:
            offset = (offset + length / 2.0) % length - length / 2.0
        return np.exp(-0.5 * (offset / sigma_px) ** 2).astype(np.float32)

    return axis_weights(px[:, 1], height).T @ axis_weights(px[:, 0], width)


def _zero_mean(weight: torch.Tensor) -> torch.Tensor:
    return weight - weight.mean(dim=(1, 2, 3), keepdim=True)


class RandomMultiScaleCNN(nn.Module):
    """Fixed-seed random CNN with a multi-scale first layer; see the module docstring.

    Input: (B, 1, H, W) rasters normalised to mean 1. Output: two maps
    (B, 64, H/2, W/2) and (B, 128, H/4, W/4).
    """

    KERNEL_SIZES = (3, 5, 7, 11)

    def __init__(self, seed: int = 0) -> None:
        super().__init__()
        generator = torch.Generator().manual_seed(seed)
        per_scale = LAYER_CHANNELS[0] // len(self.KERNEL_SIZES)
        self.first = nn.ModuleList()
        for size in self.KERNEL_SIZES:
            conv = nn.Conv2d(1, per_scale, size, padding=size // 2, bias=False)
            conv.weight.data = _zero_mean(torch.randn(conv.weight.shape, generator=generator)) / size
            self.first.append(conv)
        self.second = nn.Conv2d(LAYER_CHANNELS[0], LAYER_CHANNELS[1], 3, padding=2, dilation=2, bias=False)
        fan_in = LAYER_CHANNELS[0] * 9
        self.second.weight.data = _zero_mean(torch.randn(self.second.weight.shape, generator=generator)) / math.sqrt(fan_in)
        self.pool = nn.AvgPool2d(2)
        self.requires_grad_(False)

    def forward(self, images: torch.Tensor) -> list[torch.Tensor]:
        layer1 = self.pool(torch.relu(torch.cat([conv(images) for conv in self.first], dim=1)))
        layer2 = self.pool(torch.relu(self.second(layer1)))
        return [layer1, layer2]


class VGG16Blocks(nn.Module):
    """VGG-16's first two convolution blocks, returning pool1 (64 ch) and pool2 (128 ch).

    Input: (B, 1, H, W) rasters in [0, inf) (dark dots = high); they are shown
    to the network as black dots on white, replicated to RGB and normalised
    with the ImageNet statistics.
    """

    # torchvision's vgg16 ``features`` indices of the four convolutions used here
    TORCHVISION_INDICES = (0, 2, 5, 7)

    def __init__(self, weights: Path | str) -> None:
        super().__init__()
        self.convs = nn.ModuleList(
            [nn.Conv2d(3, 64, 3, padding=1), nn.Conv2d(64, 64, 3, padding=1), nn.Conv2d(64, 128, 3, padding=1), nn.Conv2d(128, 128, 3, padding=1)]
        )
        self.pool = nn.MaxPool2d(2)
        self.load_torchvision(weights)
        self.requires_grad_(False)
        self.register_buffer("mean", torch.tensor(_IMAGENET_MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(_IMAGENET_STD).view(1, 3, 1, 1))

    def load_torchvision(self, weights: Path | str) -> None:
        path = Path(weights)
        if not path.is_file():
            raise PatternshopError(f"{path}: VGG-16 weights not found (give a local torchvision-format .pth file)")
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:  # torch raises several types for a bad file
            raise PatternshopError(f"{path}: not a readable PyTorch weights file ({exc})") from exc
        try:
            for conv, index in zip(self.convs, self.TORCHVISION_INDICES):
                conv.weight.data.copy_(state[f"features.{index}.weight"])
                conv.bias.data.copy_(state[f"features.{index}.bias"])
        except (KeyError, RuntimeError) as exc:
            raise PatternshopError(f"{path}: not VGG-16 weights in torchvision format ({exc})") from exc

    def forward(self, images: torch.Tensor) -> list[torch.Tensor]:
        rgb = (1.0 - images.clamp(0.0, 1.0)).expand(-1, 3, -1, -1)
        x = (rgb - self.mean) / self.std
        x = torch.relu(self.convs[1](torch.relu(self.convs[0](x))))
        pool1 = self.pool(x)
        x = torch.relu(self.convs[3](torch.relu(self.convs[2](pool1))))
        return [pool1, self.pool(x)]


@dataclass
class FeatureExtractor:
    """Gram-matrix features of point patterns (see the module docstring).

    Attributes:
        name: ``"random-cnn"`` or ``"vgg16"``.
        seed: seed of the random CNN.
        weights: local VGG-16 weights file (``vgg16`` only).
    """

    name: str = "random-cnn"
    seed: int = 0
    weights: str | None = None
    network: nn.Module = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.name == "random-cnn":
            self.network = RandomMultiScaleCNN(self.seed)
        elif self.name == "vgg16":
            if not self.weights:
                raise PatternshopError("the vgg16 extractor needs a local weights file (features.weights=...)")
            self.network = VGG16Blocks(self.weights)
        else:
            raise PatternshopError(f"unknown feature extractor '{self.name}' (use random-cnn or vgg16)")
        self.network.eval()

    def describe(self) -> dict:
        """What built the features, for provenance records."""
        return {"name": self.name, "version": FEATURES_VERSION, "seed": self.seed, "weights": self.weights, "splat_sigmas": list(SPLAT_SIGMAS),
                "corpus_points": CORPUS_POINTS, "pixels_per_unit": PIXELS_PER_UNIT, "margin_pixels": MARGIN_PIXELS}

    def rasters(self, points: np.ndarray, domain: tuple[float, float], periodic: bool) -> np.ndarray:
        """(3, H, W) splat rasters of a pattern brought to the corpus density."""
        points = np.asarray(points, np.float64)
        w, h = domain
        scale = math.sqrt(len(points) / (w * h) / CORPUS_POINTS)  # domain units -> corpus units
        points, (w, h) = points * scale, (w * scale, h * scale)
        side = math.sqrt(WINDOW_POINTS / CORPUS_POINTS)
        if not periodic and (w > side or h > side):  # central window
            lo = np.array([max(0.0, (w - side) / 2), max(0.0, (h - side) / 2)])
            w, h = min(w, side), min(h, side)
            points = points - lo
            points = points[np.all((points >= 0) & (points <= [w, h]), axis=1)]
        size = (max(1, round(h * PIXELS_PER_UNIT)), max(1, round(w * PIXELS_PER_UNIT)))
        if min(size) <= 2 * MARGIN_PIXELS + 8:
            raise PatternshopError(f"too few points ({len(points)}) in the pattern to measure its correlation")
        return np.stack([splat_raster(points, size, sigma, PIXELS_PER_UNIT, periodic) for sigma in SPLAT_SIGMAS])

    @torch.no_grad()
    def __call__(self, points: np.ndarray, domain: tuple[float, float] = (1.0, 1.0), periodic: bool = False) -> np.ndarray:
        """(61440,) float32 Gram features of points (n, 2) in ``[0, w] x [0, h]``."""
        rasters = torch.from_numpy(self.rasters(points, domain, periodic))
        rasters = rasters / rasters.mean(dim=(1, 2), keepdim=True).clamp_min(1e-12)
        grams = []
        for level, maps in enumerate(self.network(rasters[:, None])):
            margin = MARGIN_PIXELS >> (level + 1)
            maps = maps[:, :, margin:-margin, margin:-margin].flatten(2)
            grams.append((maps @ maps.transpose(1, 2) / maps.shape[-1]).flatten(1))
        # order: for each splat size, layer-1 Gram then layer-2 Gram
        return torch.cat(grams, dim=1).reshape(-1).numpy()


def scale_blocks(features: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Copy of features (..., 61440) with each of the 6 Gram blocks multiplied by its weight (6,)."""
    scaled = np.array(features, np.float32, copy=True)
    for block, weight in zip(block_slices(), weights):
        scaled[..., block] *= weight
    return scaled


def block_slices() -> list[slice]:
    """Slices of the 2 x 3 Gram blocks (layer, splat size) in a feature vector."""
    slices, start = [], 0
    for _ in SPLAT_SIGMAS:
        for channels in LAYER_CHANNELS:
            slices.append(slice(start, start + channels * channels))
            start += channels * channels
    return slices
