"""CelebAMask-HQ faces: two maps per image, one with uniform chroma, one with a chroma per segment.

Layout under ``root`` (as distributed)::

    CelebA-HQ-img/<id>.jpg                                 1024 x 1024 photographs
    CelebAMask-HQ-mask-anno/<id // 2000>/<id:05d>_<part>.png   512 x 512 part masks (white = part)

Item ``2 i`` is image i with one random latent everywhere; item ``2 i + 1``
gives each segment group (``segments``: group -> part names; pixels in no
listed part are background) its own random latent. Parts listed later win
where masks overlap. An image without any mask file is skipped for its
segment item only.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from data_gen.chroma import segment_chroma, uniform_chroma
from data_gen.makers.base import MapMaker, SourceError, load_density, read_image, require_dir
from synthesis.labmap import LabMap

IMAGE_DIR = "CelebA-HQ-img"
MASK_DIR = "CelebAMask-HQ-mask-anno"
DEFAULT_SEGMENTS = {  # the paper names skin, hair and background; small parts join the skin
    "skin": ["skin", "nose", "l_eye", "r_eye", "eye_g", "l_brow", "r_brow", "l_ear", "r_ear", "mouth", "u_lip", "l_lip", "ear_r"],
    "neck": ["neck", "neck_l"],
    "cloth": ["cloth"],
    "hair": ["hair", "hat"],
}
_MASK_NAME = re.compile(r"^(\d+)_([a-z_]+)\.png$")


class FacesMaker(MapMaker):
    name = "faces"
    layout = f"CelebAMask-HQ: <root>/{IMAGE_DIR}/<id>.jpg and <root>/{MASK_DIR}/<k>/<id:05d>_<part>.png"

    def __init__(self, size: int, root: str | None = None, segments: Mapping[str, Sequence[str]] | None = None,
                 palette: str | None = None) -> None:
        super().__init__(size, palette)
        folder = require_dir(root, self.name, self.layout)
        images = folder / IMAGE_DIR
        if not images.is_dir():
            raise SourceError(f"dataset faces: {images} not found ({self.layout})")
        self.images = sorted((path for path in images.iterdir() if path.suffix.lower() in (".jpg", ".jpeg", ".png")
                              and path.stem.isdigit()), key=lambda path: int(path.stem))
        if not self.images:
            raise SourceError(f"dataset faces: no <id>.jpg images in {images}")
        self.segments = {group: list(parts) for group, parts in (segments or DEFAULT_SEGMENTS).items()}
        self.masks: dict[int, dict[str, Path]] = {}
        mask_root = folder / MASK_DIR
        for path in sorted(mask_root.rglob("*.png")) if mask_root.is_dir() else []:
            match = _MASK_NAME.match(path.name)
            if match:
                self.masks.setdefault(int(match.group(1)), {})[match.group(2)] = path

    def __len__(self) -> int:
        return 2 * len(self.images)

    def source(self, index: int) -> str:
        return f"{self.images[index // 2]} ({'segments' if index % 2 else 'uniform'})"

    def labels(self, image_id: int) -> np.ndarray:
        """(size, size) int segment labels: 0 background, k the k-th group of ``segments``."""
        parts = self.masks.get(image_id)
        if not parts:
            raise SourceError(f"faces: no masks for image {image_id} under {MASK_DIR}/")
        labels = np.zeros((self.size, self.size), np.int64)
        for label, members in enumerate(self.segments.values(), start=1):
            for part in members:
                if part not in parts:
                    continue
                labels[read_image(parts[part], self.size, "L", Image.Resampling.NEAREST) > 127] = label
        return labels

    def make(self, index: int, rng: np.random.Generator) -> LabMap:
        path = self.images[index // 2]
        density = load_density(path, self.size)  # the photos are square; the masks cover the same frame
        if index % 2:
            latent = segment_chroma(self.labels(int(path.stem)), rng, self.palette)
        else:
            latent = uniform_chroma(density.shape, rng, self.palette)
        return self.finish(density, latent, index)
