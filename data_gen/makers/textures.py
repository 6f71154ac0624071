"""Procedural texture pictures with fine detail: the pictures the network must not blur.

One function per texture, ``(size, rng) -> (size, size) float32 density in [0, 1]`` (1 = full ink),
deterministic given ``rng``:

================  ===========================================================================
texture           what it draws
================  ===========================================================================
``fractal``       fractal (fBm) noise, 1/f^beta with beta in [0.8, 2.2]; one in three ridged
                  (|noise| folded, sharp creases)
``gabor``         sparse-convolution Gabor noise: Poisson impulses convolved with one or two
                  Gabor kernels (period 3-24 px, random orientation): oriented fine texture
``hatching``      2-5 regions (Voronoi), each hatched with lines (period 3-14 px, width
                  15-60 % of it, random angle), one in two cross-hatched
``cells``         Worley (cellular) noise: F1 or F2 - F1 distance to 20-600 random features
``text``          lines of random characters in Pillow's default font (8-40 px), ink on a
                  light background
``line_art``      3-40 strokes (polylines, Bezier curves, circles, 1-5 px) on a light
                  background, some shapes filled
``dead_leaves``   the dead leaves model: occluding disks of random grey, radii with density
                  r^-3 from 2 px to 10-40 % of the map (scale invariant, as the edges of
                  natural images), a third of them slightly blurred (as a photograph's focus);
                  opt-in (not in :data:`DEFAULT_TEXTURES`, so the recorded commands of
                  earlier folders make the same pairs)
================  ===========================================================================

They are opt-in map sources: ``textures.share`` > 0 in the pair generation config
(``conf/generation/default.yaml``, :func:`data_gen.pairs.texture_variant`) replaces that share of the
maps' density by one of these pictures (weights ``textures.kinds``), keeping the map's correlation
field; or ``dataset=textures`` (:class:`TexturesMaker`) makes every map from them.
"""

from __future__ import annotations

import string
from collections.abc import Callable, Mapping

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from data_gen.chroma import gaussian_field_chroma, uniform_chroma
from data_gen.makers.base import MapMaker
from data_gen.makers.procedural import _normalise
from synthesis.labmap import LabMap

SUPERSAMPLE = 2  # strokes and letters are drawn at twice the size and box-filtered (anti-aliased)
CHARACTERS = string.ascii_letters + string.digits + ".,;:!?&@#%()-"
MIN_MEAN = 0.05  # a picture lighter than this on average gets a background tone (the maker skips maps < 0.02)


def _frequencies(size: int) -> np.ndarray:
    fy, fx = np.meshgrid(np.fft.fftfreq(size), np.fft.fftfreq(size), indexing="ij")
    return np.hypot(fx, fy) * size


def fractal(size: int, rng: np.random.Generator) -> np.ndarray:
    """fBm noise with a 1/f^beta amplitude spectrum (beta in [0.8, 2.2]); one in three ridged."""
    beta = rng.uniform(0.8, 2.2)
    frequency = _frequencies(size)
    gain = np.where(frequency > 0, np.maximum(frequency, 1.0) ** -beta, 0.0)
    noise = np.fft.ifft2(np.fft.fft2(rng.standard_normal((size, size))) * gain).real
    if rng.random() < 1 / 3:
        noise = -np.abs(noise - np.median(noise))
    return _normalise(noise).astype(np.float32)


def gabor(size: int, rng: np.random.Generator) -> np.ndarray:
    """Sparse-convolution Gabor noise: random-weight impulses (about one per 6 px^2) convolved with one or two
    Gabor kernels ``exp(-pi (r/width)^2) cos(2 pi x'/period + phase)``, circularly (FFT)."""
    total = np.zeros((size, size))
    rows, cols = np.mgrid[0:size, 0:size]
    dy, dx = np.where(rows < size - rows, rows, rows - size), np.where(cols < size - cols, cols, cols - size)
    for _ in range(int(rng.integers(1, 3))):
        period = float(np.exp(rng.uniform(np.log(3.0), np.log(24.0))))
        width = period * rng.uniform(1.0, 3.0)
        angle = rng.uniform(0, np.pi)
        along = dx * np.cos(angle) + dy * np.sin(angle)
        kernel = np.exp(-np.pi * (dx**2 + dy**2) / width**2) * np.cos(2 * np.pi * along / period + rng.uniform(0, 2 * np.pi))
        impulses = (rng.random((size, size)) < 1 / 6) * rng.uniform(-1, 1, (size, size))
        total += np.fft.ifft2(np.fft.fft2(impulses) * np.fft.fft2(kernel)).real
    return _normalise(total).astype(np.float32)


def hatching(size: int, rng: np.random.Generator) -> np.ndarray:
    """2-5 Voronoi regions, each hatched (period 3-14 px, line width 15-60 % of it, random angle), one in two
    cross-hatched; lines anti-aliased by their distance in pixels."""
    from scipy.spatial import cKDTree

    rows, cols = np.mgrid[0:size, 0:size] + 0.5
    regions = int(rng.integers(2, 6))
    _, owner = cKDTree(rng.random((regions, 2)) * size).query(np.stack([cols.ravel(), rows.ravel()], 1))
    owner = owner.reshape(size, size)
    density = np.zeros((size, size))
    for region in range(regions):
        ink = np.zeros((size, size))
        angle = rng.uniform(0, np.pi)
        for layer in range(1 + int(rng.random() < 0.5)):
            period = rng.uniform(3.0, 14.0)
            half = 0.5 * period * rng.uniform(0.15, 0.6)
            if layer:  # the cross-hatch: 45-135 degrees from the first
                angle += rng.uniform(np.pi / 4, 3 * np.pi / 4)
            phase = (cols * np.cos(angle) + rows * np.sin(angle)) % period
            distance = np.abs(phase - period / 2)  # px from the line's centre
            ink = np.maximum(ink, np.clip(half + 0.5 - distance, 0.0, 1.0))
        density[owner == region] = (ink * rng.uniform(0.5, 1.0))[owner == region]
    return density.astype(np.float32)


def cells(size: int, rng: np.random.Generator) -> np.ndarray:
    """Worley noise: distance to the nearest of 20-600 random features (F1), or F2 - F1 (cell walls), random polarity."""
    from scipy.spatial import cKDTree

    count = int(np.exp(rng.uniform(np.log(20), np.log(600))))
    features = rng.random((count, 2)) * size
    rows, cols = np.mgrid[0:size, 0:size] + 0.5
    distance, _ = cKDTree(features).query(np.stack([cols.ravel(), rows.ravel()], 1), k=2)
    value = distance[:, 0] if rng.random() < 0.5 else distance[:, 1] - distance[:, 0]
    value = _normalise(value.reshape(size, size))
    return (value if rng.random() < 0.5 else 1.0 - value).astype(np.float32)


def _font(pixels: int) -> ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=pixels)  # Pillow >= 10.1 with FreeType: a scalable default font
    except TypeError:  # older Pillow: the fixed bitmap font
        return ImageFont.load_default()


def text(size: int, rng: np.random.Generator) -> np.ndarray:
    """Lines of random characters in Pillow's default font (8-40 px at the map size), dark on white."""
    big = size * SUPERSAMPLE
    image = Image.new("L", (big, big), 0)
    draw = ImageDraw.Draw(image)
    height = int(rng.integers(8, 41)) * SUPERSAMPLE
    font = _font(height)
    y = float(rng.uniform(-height, height))
    while y < big:
        words = [''.join(rng.choice(list(CHARACTERS), size=int(rng.integers(1, 9)))) for _ in range(int(rng.integers(2, 12)))]
        draw.text((float(rng.uniform(-big / 4, big / 8)), y), " ".join(words), fill=int(rng.integers(160, 256)), font=font)
        y += height * rng.uniform(1.1, 1.8)
    return (np.asarray(image.resize((size, size), Image.Resampling.BOX), np.float32) / 255.0)


def line_art(size: int, rng: np.random.Generator) -> np.ndarray:
    """3-40 strokes (polylines, quadratic Bezier curves, circles; 1-5 px wide), a few shapes filled, dark on white."""
    big = size * SUPERSAMPLE
    image = Image.new("L", (big, big), 0)
    draw = ImageDraw.Draw(image)
    for _ in range(int(rng.integers(3, 41))):
        width = int(rng.integers(1, 6)) * SUPERSAMPLE
        ink = int(rng.integers(150, 256))
        kind = rng.random()
        if kind < 0.35:
            points = [tuple(p) for p in (rng.random((int(rng.integers(2, 7)), 2)) * big).tolist()]
            draw.line(points, fill=ink, width=width, joint="curve")
        elif kind < 0.7:
            p0, p1, p2 = rng.random((3, 2)) * big
            t = np.linspace(0, 1, 64)[:, None]
            curve = (1 - t) ** 2 * p0 + 2 * (1 - t) * t * p1 + t**2 * p2
            draw.line([tuple(p) for p in curve.tolist()], fill=ink, width=width, joint="curve")
        else:
            cx, cy = rng.random(2) * big
            radius = rng.uniform(0.02, 0.3) * big
            box = [cx - radius, cy - radius, cx + radius, cy + radius]
            if rng.random() < 0.25:
                draw.ellipse(box, fill=int(ink * rng.uniform(0.2, 0.7)), outline=ink, width=width)
            else:
                draw.ellipse(box, outline=ink, width=width)
    return (np.asarray(image.resize((size, size), Image.Resampling.BOX), np.float32) / 255.0)


LEAVES_COVERAGE = 4.0  # disks drawn: this many times the map's area over a disk's mean area (the last on top)


def leaf_radii(count: int, low: float, high: float, rng: np.random.Generator) -> np.ndarray:
    """(count,) radii in [low, high] drawn with density proportional to r^-3 (inverse CDF of uniform draws)."""
    return (low**-2 - rng.random(count) * (low**-2 - high**-2)) ** -0.5


def dead_leaves(size: int, rng: np.random.Generator) -> np.ndarray:
    """The dead leaves model: disks of uniform random grey, each on top of the ones before, radii drawn with
    density proportional to r^-3 between 2 px (about a point spacing of the
    development and test stipplings' maps) and 10-40 % of ``size`` (inverse CDF), drawn at twice the size and
    box-filtered; a third of the pictures then blurred by a Gaussian of 0.5-1.5 px."""
    from scipy.ndimage import gaussian_filter

    big = size * SUPERSAMPLE
    low, high = 2.0, size * rng.uniform(0.1, 0.4)
    mean_square = np.log(high / low) / (0.5 * (low**-2 - high**-2))  # E[r^2] under the r^-3 density
    count = int(LEAVES_COVERAGE * size * size / (np.pi * mean_square))
    radii = leaf_radii(count, low, high, rng) * SUPERSAMPLE
    centres = rng.random((count, 2)) * big
    greys = rng.integers(0, 256, count)
    image = Image.new("L", (big, big), int(rng.integers(0, 256)))
    draw = ImageDraw.Draw(image)
    for (x, y), radius, grey in zip(centres.tolist(), radii.tolist(), greys.tolist(), strict=True):
        draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=grey)
    picture = np.asarray(image.resize((size, size), Image.Resampling.BOX), np.float32) / 255.0
    if rng.random() < 1 / 3:
        picture = gaussian_filter(picture, rng.uniform(0.5, 1.5), mode="reflect")
    return picture


TEXTURES: dict[str, Callable[[int, np.random.Generator], np.ndarray]] = {
    "fractal": fractal, "gabor": gabor, "hatching": hatching, "cells": cells, "text": text, "line_art": line_art,
    "dead_leaves": dead_leaves,
}
DEFAULT_TEXTURES = {name: 1.0 for name in TEXTURES if name != "dead_leaves"}  # the six of the earlier folders


def choose(rng: np.random.Generator, weights: Mapping[str, float]) -> str:
    """A name of ``weights`` drawn by weight (sorted names: the draw does not depend on the mapping's order)."""
    names = sorted(weights)
    p = np.array([weights[name] for name in names], dtype=np.float64)
    return names[int(rng.choice(len(names), p=p / p.sum()))]


def texture_picture(size: int, rng: np.random.Generator, kinds: Mapping[str, float] | None = None) -> tuple[str, np.ndarray]:
    """(kind, (size, size) float32 density in [0, 1]): a texture drawn by ``kinds`` weights, then a random gamma and
    range (a light one gets a background tone so its mean density is at least :data:`MIN_MEAN`)."""
    kind = choose(rng, kinds or DEFAULT_TEXTURES)
    density = np.clip(TEXTURES[kind](size, rng), 0.0, 1.0) ** float(np.exp(rng.normal(0.0, 0.3)))
    low = 0.0 if rng.random() < 0.5 else rng.uniform(0.0, 0.25)
    high = rng.uniform(max(low + 0.3, 0.6), 1.0)
    density = low + (high - low) * density
    mean = float(density.mean())
    if mean < MIN_MEAN:  # mostly white (sparse text, thin lines): lift the background
        background = (MIN_MEAN - mean) / max(1.0 - mean, 1e-9)
        density = background + (1.0 - background) * density
    return kind, np.clip(density, 0.0, 1.0).astype(np.float32)


def check_kinds(kinds: Mapping[str, float]) -> dict[str, float]:
    """Texture weights checked (known names, weights >= 0 with a positive sum)."""
    kinds = {str(name): float(weight) for name, weight in kinds.items()}
    unknown = sorted(set(kinds) - set(TEXTURES))
    if unknown:
        raise ValueError(f"unknown textures {unknown}; choose from {', '.join(TEXTURES)}")
    if min(kinds.values(), default=0.0) < 0 or sum(kinds.values()) <= 0:
        raise ValueError("texture weights must be >= 0 with a positive sum")
    return kinds


class TexturesMaker(MapMaker):
    """``items`` texture maps (:data:`TEXTURES`), with a uniform correlation or a smooth Gaussian field of them."""

    name = "textures"
    finite = False

    def __init__(self, size: int, items: int = 2000, kinds: Mapping[str, float] | None = None,
                 uniform_share: float = 0.5, palette: str | None = None) -> None:
        from synthesis.errors import PatternshopError

        super().__init__(size, palette)
        self.items = int(items)
        try:
            self.kinds = check_kinds(kinds or DEFAULT_TEXTURES)
        except ValueError as exc:
            raise PatternshopError(f"dataset textures: {exc}") from exc
        self.uniform_share = float(uniform_share)

    def __len__(self) -> int:
        return self.items

    def source(self, index: int) -> str:
        return f"texture item {index}"

    def make(self, index: int, rng: np.random.Generator) -> LabMap:
        _, density = texture_picture(self.size, rng, self.kinds)
        shape = density.shape
        if rng.random() < self.uniform_share:
            latent = uniform_chroma(shape, rng, self.palette)
        else:
            latent = gaussian_field_chroma(shape, rng, self.palette)
        return self.finish(density, latent, index)
