"""What every map maker shares: the interface, the error for bad sources, image loading."""

from __future__ import annotations

import os
from abc import ABC, abstractmethod
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from synthesis.errors import PatternshopError
from synthesis.labmap import LabMap
from synthesis.palette import Palette, load_palette

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
MIN_INK = 0.02  # a map whose mean density is below this has (almost) no points: skipped


class SourceError(PatternshopError):
    """A source item cannot become a map (unreadable image, missing mask, empty tile); it is skipped."""


class MapMaker(ABC):
    """Item index -> target map. Subclasses set ``name`` and implement the three methods.

    ``finite`` makers read a source with ``len(maker)`` items; a non-finite one
    (procedural) makes as many items as asked, ``len`` being its default count.
    """

    name = "maker"
    finite = True

    def __init__(self, size: int, palette: str | None = None) -> None:
        self.size = int(size)
        self.palette_path = palette
        self.unreadable: list[str] = []  # sources dropped while indexing (reported with the skipped items)

    @property
    def palette(self) -> Palette:
        return load_palette(self.palette_path)

    @classmethod
    def from_config(cls, options: Mapping[str, Any], size: int) -> MapMaker:
        """Build from a dataset config's options (everything but ``name``)."""
        return cls(size=size, **dict(options))

    @abstractmethod
    def __len__(self) -> int:
        """Number of items the source offers."""

    @abstractmethod
    def source(self, index: int) -> str:
        """Where item ``index`` comes from (a path, a tile, a seed), for manifests and skip lists."""

    @abstractmethod
    def make(self, index: int, rng: np.random.Generator) -> LabMap:
        """The (size, size) target map of item ``index``; raises :class:`SourceError` for a bad source."""

    def finish(self, density: np.ndarray, latent: np.ndarray, index: int) -> LabMap:
        """A map from density (H, W) and latent (H, W, 2); a (nearly) white one is a :class:`SourceError`."""
        if float(np.mean(density)) < MIN_INK:
            raise SourceError(f"{self.source(index)}: nearly white (mean density {np.mean(density):.3f} < {MIN_INK})")
        return LabMap.from_density_latent(density, latent)


def require_dir(path: str | os.PathLike | None, dataset: str, layout: str) -> Path:
    """``path`` as a directory, or a one-line error saying which layout ``dataset`` expects."""
    if path is None or str(path) in ("", "???"):
        raise PatternshopError(f"dataset {dataset}: set dataset.root=/path/to/data ({layout})")
    folder = Path(path).expanduser()
    if not folder.is_dir():
        raise PatternshopError(f"dataset {dataset}: {folder} is not a folder ({layout})")
    return folder


def find_images(folder: Path, suffixes: Iterable[str] = IMAGE_SUFFIXES) -> list[Path]:
    """Image files under ``folder`` (recursive), sorted, so item numbers are stable."""
    wanted = {suffix.lower() for suffix in suffixes}
    return sorted(path for path in folder.rglob("*") if path.suffix.lower() in wanted and path.is_file())


def square_resize(image: Image.Image, size: int, resample: int = Image.Resampling.BOX) -> Image.Image:
    """Centre-crop to a square, then resize to size x size."""
    width, height = image.size
    side = min(width, height)
    left, top = (width - side) // 2, (height - side) // 2
    return image.crop((left, top, left + side, top + side)).resize((size, size), resample)


def read_image(path: Path, size: int, mode: str = "RGB", resample: int = Image.Resampling.BOX) -> np.ndarray:
    """(size, size[, C]) uint8 pixels of an image converted to ``mode``, centre-cropped square and resized.

    Raises:
        SourceError: the file is missing, truncated or not an image.
    """
    try:
        with Image.open(path) as image:
            return np.asarray(square_resize(image.convert(mode), size, resample))
    except Exception as exc:  # noqa: BLE001 - Pillow's decoders raise many types (OSError, SyntaxError, struct.error...)
        raise SourceError(f"{path}: unreadable image ({exc})") from exc


def load_density(path: Path, size: int) -> np.ndarray:
    """(size, size) density 1 - L*/100 of an image (sRGB, D65), centre-cropped and area-resized."""
    rgb = read_image(path, size).astype(np.float32) / 255.0
    return 1.0 - LabMap.from_srgb(rgb).L / 100.0
