"""Procedural training maps: varied pictures drawn from the item's seed, nothing to download.

The default model is trained on these, so they aim at the variety of real
pictures rather than at one kind of image. A picture is one of:

* ``layers`` — a background fill and 1-6 overlaid shapes (ellipses, rotated
  rectangles, star polygons, rings, bands, text), each with its own fill;
  hard or blurred edges.
* ``voronoi`` — a partition into 3-16 cells, each with a constant or varying fill.
* ``dead_leaves`` — 20-200 occluding discs and polygons with power-law sizes
  (the dead-leaves model has the scale statistics of natural images).
* ``texture`` — 1/f^beta noise under a lighting gradient with a few soft shapes,
  photograph-like.

Fills are constants, linear or radial gradients, smooth noise, 1/f noise or
sinusoidal stripes. The density is then given a random gamma and a random
range (sometimes reaching 0, like a white photographic background).

Chroma (:mod:`data_gen.chroma`): ``uniform``; ``segments`` — one latent per
region of the picture (so correlation edges follow density edges) or, one
time in three, per region of an independent partition (edges of their own);
``gaussians`` — a smooth field. Mix weights are configurable.
"""

from __future__ import annotations

import string
from collections.abc import Callable, Mapping

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from data_gen.chroma import gaussian_field_chroma, segment_chroma, uniform_chroma
from data_gen.makers.base import MapMaker
from synthesis.labmap import LabMap

DEFAULT_KINDS = {"layers": 0.45, "voronoi": 0.15, "dead_leaves": 0.2, "texture": 0.2}
DEFAULT_CHROMA = {"uniform": 0.3, "segments": 0.4, "gaussians": 0.3}
SUPERSAMPLE = 2  # shapes are drawn at twice the map size and box-filtered (anti-aliased edges)
TEXT_CHARACTERS = string.ascii_letters + string.digits + "&@#%?!"


def _choose(rng: np.random.Generator, weights: Mapping[str, float]) -> str:
    names = list(weights)
    p = np.array([weights[name] for name in names], dtype=np.float64)
    return names[int(rng.choice(len(names), p=p / p.sum()))]


def _normalise(image: np.ndarray) -> np.ndarray:
    """Rescale to [0, 1] between the 1st and 99th percentiles (clipped)."""
    low, high = np.percentile(image, [1, 99])
    return np.clip((image - low) / max(high - low, 1e-9), 0.0, 1.0)


class Canvas:
    """Pixel-centre coordinates of a size x size map in [0, 1] and the drawing primitives on it."""

    def __init__(self, size: int, rng: np.random.Generator) -> None:
        self.size, self.rng = size, rng
        rows, cols = np.mgrid[0:size, 0:size]
        self.x, self.y = (cols + 0.5) / size, (rows + 0.5) / size

    # --- fills: (H, W) in [0, 1] -------------------------------------------
    def spectral_noise(self, beta: float | None = None, sigma: float | None = None) -> np.ndarray:
        """Noise with a 1/f^beta amplitude spectrum, or Gaussian-smoothed (sigma in map units)."""
        frequency = np.hypot(*np.meshgrid(np.fft.fftfreq(self.size), np.fft.fftfreq(self.size), indexing="ij")) * self.size
        if beta is not None:
            gain = np.where(frequency > 0, np.maximum(frequency, 1.0) ** -beta, 0.0)
        else:
            gain = np.exp(-0.5 * (frequency * 2 * np.pi * sigma) ** 2)
        spectrum = np.fft.fft2(self.rng.standard_normal((self.size, self.size))) * gain
        return _normalise(np.fft.ifft2(spectrum).real)

    def fill(self) -> np.ndarray:
        rng = self.rng
        low, high = rng.random(2)
        kind = _choose(rng, {"constant": 0.3, "linear": 0.2, "radial": 0.12, "smooth": 0.15, "power": 0.13, "stripes": 0.1})
        if kind == "constant":
            return np.full((self.size, self.size), low)
        if kind == "linear":
            angle = rng.uniform(0, 2 * np.pi)
            t = self.x * np.cos(angle) + self.y * np.sin(angle)
            t = (t - t.min()) / max(t.max() - t.min(), 1e-9)
        elif kind == "radial":
            centre, radius = rng.random(2), rng.uniform(0.2, 0.9)
            t = np.clip(np.hypot(self.x - centre[0], self.y - centre[1]) / radius, 0.0, 1.0)
        elif kind == "smooth":
            t = self.spectral_noise(sigma=rng.uniform(0.015, 0.15))
        elif kind == "power":
            t = self.spectral_noise(beta=rng.uniform(1.5, 3.0))
        else:
            angle, cycles = rng.uniform(0, np.pi), rng.uniform(1.0, 8.0)
            t = 0.5 + 0.5 * np.sin(2 * np.pi * cycles * (self.x * np.cos(angle) + self.y * np.sin(angle)) + rng.uniform(0, 2 * np.pi))
            if rng.random() < 0.4:
                t = (t > 0.5).astype(np.float64)
        return low + (high - low) * t

    # --- shapes: coverage (H, W) in [0, 1] ---------------------------------
    def _draw(self, paint: Callable[[ImageDraw.ImageDraw, int], None]) -> np.ndarray:
        big = self.size * SUPERSAMPLE
        image = Image.new("L", (big, big), 0)
        paint(ImageDraw.Draw(image), big)
        return np.asarray(image.resize((self.size, self.size), Image.Resampling.BOX), dtype=np.float64) / 255.0

    def _outline(self, radii: np.ndarray, angles: np.ndarray, big: int, centre: np.ndarray, scale: np.ndarray,
                 rotation: float) -> list[tuple[float, float]]:
        x, y = radii * np.cos(angles) * scale[0], radii * np.sin(angles) * scale[1]
        c, s = np.cos(rotation), np.sin(rotation)
        return [(float((centre[0] + c * u - s * v) * big), float((centre[1] + s * u + c * v) * big)) for u, v in zip(x, y)]

    def shape(self) -> np.ndarray:
        rng = self.rng
        kind = _choose(rng, {"ellipse": 0.25, "rectangle": 0.2, "polygon": 0.2, "ring": 0.1, "band": 0.1, "text": 0.15})
        centre = rng.uniform(0.1, 0.9, 2)
        scale = rng.uniform(0.08, 0.45, 2)
        rotation = rng.uniform(0, np.pi)
        if kind == "text":
            return self.text()

        def paint(draw: ImageDraw.ImageDraw, big: int) -> None:
            if kind in ("ellipse", "ring"):
                angles = np.linspace(0, 2 * np.pi, 96, endpoint=False)
                draw.polygon(self._outline(np.ones(96), angles, big, centre, scale, rotation), fill=255)
                if kind == "ring":
                    draw.polygon(self._outline(np.full(96, rng.uniform(0.4, 0.8)), angles, big, centre, scale, rotation), fill=0)
            elif kind == "rectangle":
                angles = np.array([0.25, 0.75, 1.25, 1.75]) * np.pi
                draw.polygon(self._outline(np.full(4, np.sqrt(2)), angles, big, centre, scale, rotation), fill=255)
            elif kind == "polygon":
                corners = int(rng.integers(3, 10))
                angles = np.sort(rng.uniform(0, 2 * np.pi, corners))
                draw.polygon(self._outline(rng.uniform(0.3, 1.0, corners), angles, big, centre, scale, rotation), fill=255)
            else:  # band: a thick straight stroke across the map
                ends = self._outline(np.array([2.0, 2.0]), np.array([0.0, np.pi]), big, centre, np.ones(2), rotation)
                draw.line(ends, fill=255, width=max(2, int(scale[0] * 0.5 * big)))

        return self._draw(paint)

    def text(self) -> np.ndarray:
        rng = self.rng
        word = "".join(rng.choice(list(TEXT_CHARACTERS), size=int(rng.integers(1, 7))))
        big = self.size * SUPERSAMPLE
        font = ImageFont.load_default(size=int(big * rng.uniform(0.12, 0.5)))
        layer = Image.new("L", (big, big), 0)
        ImageDraw.Draw(layer).text((big * rng.uniform(-0.1, 0.6), big * rng.uniform(-0.1, 0.6)), word, fill=255, font=font)
        layer = layer.rotate(rng.uniform(-40, 40), resample=Image.Resampling.BILINEAR, center=(big / 2, big / 2))
        return np.asarray(layer.resize((self.size, self.size), Image.Resampling.BOX), dtype=np.float64) / 255.0

    def soften(self, mask: np.ndarray) -> np.ndarray:
        """Sometimes blur a coverage mask (soft edges); usually keep it sharp."""
        if self.rng.random() < 0.3:
            from scipy.ndimage import gaussian_filter

            return gaussian_filter(mask, self.rng.uniform(0.5, 6.0))
        return mask

    def partition(self) -> np.ndarray:
        """(H, W) int labels of a random Voronoi partition (3-16 cells, random anisotropy)."""
        rng = self.rng
        seeds = rng.random((int(rng.integers(3, 17)), 2))
        stretch = np.exp(rng.normal(0.0, 0.4, 2))
        distance = ((self.x[..., None] - seeds[:, 0]) * stretch[0]) ** 2 + ((self.y[..., None] - seeds[:, 1]) * stretch[1]) ** 2
        return np.argmin(distance, axis=-1)

    def levels(self) -> np.ndarray:
        """(H, W) int labels: smooth noise cut into 2-4 levels (organic region boundaries)."""
        noise = self.spectral_noise(sigma=self.rng.uniform(0.04, 0.15))
        cuts = np.sort(self.rng.uniform(0.2, 0.8, int(self.rng.integers(1, 4))))
        return np.digitize(noise, cuts)


# --- pictures: (density (H, W) in [0, 1], labels (H, W) int) ------------------
def layers(canvas: Canvas) -> tuple[np.ndarray, np.ndarray]:
    density = canvas.fill()
    labels = np.zeros(density.shape, np.int64)
    for label in range(1, int(canvas.rng.integers(1, 7)) + 1):
        mask = canvas.soften(canvas.shape())
        density = density * (1 - mask) + canvas.fill() * mask
        labels[mask > 0.5] = label
    return density, labels


def voronoi(canvas: Canvas) -> tuple[np.ndarray, np.ndarray]:
    labels = canvas.partition()
    density = np.zeros(labels.shape)
    for label in np.unique(labels):
        cell = labels == label
        density[cell] = canvas.fill()[cell] if canvas.rng.random() < 0.4 else canvas.rng.random()
    return density, labels


def dead_leaves(canvas: Canvas) -> tuple[np.ndarray, np.ndarray]:
    rng = canvas.rng
    count = int(rng.integers(20, 201))
    groups = int(rng.integers(2, 6))  # leaves share a few chroma groups, not one each
    density = np.full((canvas.size, canvas.size), rng.random())
    labels = np.zeros(density.shape, np.int64)
    r_min, r_max = 0.02, rng.uniform(0.15, 0.4)
    radii = (r_min**-2 - rng.random(count) * (r_min**-2 - r_max**-2)) ** -0.5  # p(r) ~ r^-3, the scale-invariant law
    for radius in np.sort(radii)[::-1]:  # large leaves first, small ones fall on top
        centre = rng.random(2)
        if rng.random() < 0.6:
            leaf = np.hypot(canvas.x - centre[0], canvas.y - centre[1]) < radius
        else:
            angle = rng.uniform(0, np.pi)
            u = (canvas.x - centre[0]) * np.cos(angle) + (canvas.y - centre[1]) * np.sin(angle)
            v = -(canvas.x - centre[0]) * np.sin(angle) + (canvas.y - centre[1]) * np.cos(angle)
            leaf = (np.abs(u) < radius) & (np.abs(v) < radius * rng.uniform(0.3, 1.0))
        density[leaf] = rng.random()
        labels[leaf] = int(rng.integers(groups))
    return density, labels


def texture(canvas: Canvas) -> tuple[np.ndarray, np.ndarray]:
    rng = canvas.rng
    angle = rng.uniform(0, 2 * np.pi)
    light = canvas.x * np.cos(angle) + canvas.y * np.sin(angle)
    light = (light - light.min()) / max(np.ptp(light), 1e-9)
    density = 0.6 * canvas.spectral_noise(beta=rng.uniform(1.2, 2.6)) + 0.4 * rng.uniform(-1, 1) * light
    for _ in range(int(rng.integers(0, 4))):
        mask = canvas.soften(canvas.shape())
        density = density * (1 - mask) + canvas.fill() * mask
    return _normalise(density), canvas.levels()


PICTURES = {"layers": layers, "voronoi": voronoi, "dead_leaves": dead_leaves, "texture": texture}


def tone(density: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random gamma and output range; one map in four reaches 0 (white background)."""
    density = np.clip(density, 0.0, 1.0) ** float(np.exp(rng.normal(0.0, 0.4)))
    low = 0.0 if rng.random() < 0.25 else rng.uniform(0.0, 0.3)
    high = rng.uniform(max(low + 0.2, 0.5), 1.0)
    return (low + (high - low) * density).astype(np.float32)


class ProceduralMaker(MapMaker):
    """``items`` procedural maps (the dataset's size; ``num_items`` can ask for fewer or more)."""

    name = "procedural"
    finite = False

    def __init__(self, size: int, items: int = 2000, kinds: Mapping[str, float] | None = None,
                 chroma: Mapping[str, float] | None = None, palette: str | None = None) -> None:
        super().__init__(size, palette)
        self.items = int(items)
        self.kinds = dict(kinds or DEFAULT_KINDS)
        self.chroma = dict(chroma or DEFAULT_CHROMA)
        unknown = (set(self.kinds) - set(PICTURES)) | (set(self.chroma) - set(DEFAULT_CHROMA))
        if unknown:
            from synthesis.errors import PatternshopError

            raise PatternshopError(f"dataset procedural: unknown kinds {sorted(unknown)}; pictures: {', '.join(PICTURES)}; "
                                   f"chroma: {', '.join(DEFAULT_CHROMA)}")

    def __len__(self) -> int:
        return self.items

    def source(self, index: int) -> str:
        return f"procedural item {index}"

    def picture(self, index: int, rng: np.random.Generator) -> tuple[str, np.ndarray, np.ndarray]:
        """(kind, density (H, W) float32, labels (H, W) int) of item ``index``."""
        canvas = Canvas(self.size, rng)
        kind = _choose(rng, self.kinds)
        density, labels = PICTURES[kind](canvas)
        return kind, tone(density, rng), labels

    def make(self, index: int, rng: np.random.Generator) -> LabMap:
        _, density, labels = self.picture(index, rng)
        mode = _choose(rng, self.chroma)
        shape = density.shape
        if mode == "uniform":
            latent = uniform_chroma(shape, rng, self.palette)
        elif mode == "gaussians":
            latent = gaussian_field_chroma(shape, rng, self.palette)
        else:
            if rng.random() < 1 / 3:
                labels = Canvas(self.size, rng).partition() if rng.random() < 0.5 else Canvas(self.size, rng).levels()
            latent = segment_chroma(labels, rng, self.palette)
        return self.finish(density, latent, index)
