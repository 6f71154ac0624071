"""Any folder of images (``folder``), and LSUN churches exported as image files (``churches``).

Grey levels become density; each image gets one item whose chroma is uniform
or, with probability ``gaussian_fraction``, a smooth Gaussian field.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from data_gen.chroma import gaussian_field_chroma, uniform_chroma
from data_gen.makers.base import MapMaker, SourceError, find_images, load_density, require_dir
from synthesis.labmap import LabMap


class FolderMaker(MapMaker):
    """Images found recursively under ``root`` (png, jpg, bmp, tif, webp), sorted by path."""

    name = "folder"
    layout = "a folder of images, searched recursively"

    def __init__(self, size: int, root: str | None = None, gaussian_fraction: float = 0.0, palette: str | None = None) -> None:
        super().__init__(size, palette)
        self.root = require_dir(root, self.name, self.layout)
        self.images = self.list_images(self.root)
        if not self.images:
            raise SourceError(f"dataset {self.name}: no images under {self.root} ({self.layout})")
        self.gaussian_fraction = float(gaussian_fraction)

    def list_images(self, root: Path) -> list[Path]:
        return find_images(root)

    def __len__(self) -> int:
        return len(self.images)

    def source(self, index: int) -> str:
        return str(self.images[index])

    def make(self, index: int, rng: np.random.Generator) -> LabMap:
        density = load_density(self.images[index], self.size)
        if rng.random() < self.gaussian_fraction:
            latent = gaussian_field_chroma(density.shape, rng, self.palette)
        else:
            latent = uniform_chroma(density.shape, rng, self.palette)
        return self.finish(density, latent, index)


class ChurchesMaker(FolderMaker):
    """LSUN church_outdoor exported to image files (e.g. ``<root>/<hash>.webp``), uniform chroma."""

    name = "churches"
    layout = "LSUN church_outdoor exported as an image folder (the lmdb export script writes one file per image)"
