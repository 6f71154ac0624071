"""Copernicus Tree Cover Density rasters tiled into maps (paper Fig. 15, supplemental §1.3).

Layout: GeoTIFF files anywhere under ``root`` (``*.tif``), single band,
tree cover in percent 0-100; 254 (outside area) and 255 (no data) mark
missing pixels. Each raster is cut into non-overlapping ``tile`` x ``tile``
pixel tiles in row-major order (files sorted by path); tiles are resampled to
the map size when ``tile`` differs. Density is cover / 100 (missing pixels: 0).
Tiles with more than ``max_missing`` missing pixels, or (nearly) no trees,
are skipped. Chroma: uniform, or with probability ``gaussian_fraction`` a
smooth field of anisotropic Gaussians (the paper uses both).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import tifffile
from PIL import Image

from data_gen.chroma import gaussian_field_chroma, uniform_chroma
from data_gen.makers.base import MapMaker, SourceError, require_dir
from synthesis.labmap import LabMap


@functools.lru_cache(maxsize=2)
def _read_raster(path: Path) -> np.ndarray:
    """The first band of a GeoTIFF as a 2D array (cached: consecutive tiles share a raster)."""
    try:
        data = tifffile.imread(path, key=0)
    except Exception as exc:  # noqa: BLE001 - tifffile and its codecs raise many types for damaged files
        raise SourceError(f"{path}: unreadable GeoTIFF ({exc})") from exc
    return data if data.ndim == 2 else data[..., 0]


class TreeCoverMaker(MapMaker):
    name = "treecover"
    layout = "Tree Cover Density GeoTIFFs (*.tif, percent 0-100, 254/255 missing) anywhere under <root>"

    def __init__(self, size: int, root: str | None = None, tile: int = 256, max_missing: float = 0.05,
                 missing_values: Sequence[int] = (254, 255), gaussian_fraction: float = 0.5, palette: str | None = None) -> None:
        super().__init__(size, palette)
        folder = require_dir(root, self.name, self.layout)
        self.tile, self.max_missing = int(tile), float(max_missing)
        self.missing_values = list(missing_values)
        self.gaussian_fraction = float(gaussian_fraction)
        self.tiles: list[tuple[Path, int, int]] = []
        for path in sorted(p for p in folder.rglob("*") if p.suffix.lower() in (".tif", ".tiff") and p.is_file()):
            try:
                with tifffile.TiffFile(path) as tif:
                    height, width = tif.pages[0].shape[:2]
            except Exception as exc:  # noqa: BLE001 - a damaged file only loses its own tiles
                self.unreadable.append(f"{path}: unreadable GeoTIFF ({exc})")
                continue
            self.tiles += [(path, row, col) for row in range(0, height - self.tile + 1, self.tile)
                           for col in range(0, width - self.tile + 1, self.tile)]
        if not self.tiles:
            raise SourceError(f"dataset treecover: no {self.tile} x {self.tile} tiles in any GeoTIFF under {folder}"
                              + (f" ({len(self.unreadable)} unreadable)" if self.unreadable else ""))

    def __len__(self) -> int:
        return len(self.tiles)

    def source(self, index: int) -> str:
        path, row, col = self.tiles[index]
        return f"{path} tile at row {row}, column {col}"

    def make(self, index: int, rng: np.random.Generator) -> LabMap:
        path, row, col = self.tiles[index]
        cover = _read_raster(path)[row : row + self.tile, col : col + self.tile].astype(np.float32)
        missing = np.isin(cover, self.missing_values)
        if missing.mean() > self.max_missing:
            raise SourceError(f"{self.source(index)}: {missing.mean():.0%} missing pixels")
        density = np.where(missing, 0.0, np.clip(cover, 0.0, 100.0) / 100.0).astype(np.float32)
        if self.tile != self.size:
            density = np.asarray(Image.fromarray(density).resize((self.size, self.size), Image.Resampling.BOX))
        if rng.random() < self.gaussian_fraction:
            latent = gaussian_field_chroma(density.shape, rng, self.palette)
        else:
            latent = uniform_chroma(density.shape, rng, self.palette)
        return self.finish(density, latent, index)
