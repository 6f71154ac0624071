"""Small stand-ins of the real datasets' folder layouts, for tests and held-out evaluation.

The real datasets (CelebAMask-HQ, AFHQ, LSUN churches, Copernicus Tree Cover
Density) cannot be downloaded here. A stand-in has the dataset's exact layout
with pictures drawn by the procedural maker (:mod:`data_gen.makers.procedural`,
a seed of its own), so the readers, masks and tiling run on it end to end:

* ``faces``: ``CelebA-HQ-img/<id>.jpg`` and ``CelebAMask-HQ-mask-anno/<id // 2000>/<id:05d>_<part>.png``;
  the picture's regions become the parts ``skin``, ``hair``, ``cloth``, ``neck``
  (largest first; the rest is background);
* ``animals``: ``train/{cat,dog,wild}/<k>.png``;
* ``churches`` and ``folder``: ``<k>.jpg`` in one folder;
* ``treecover``: one ``tile-<k>.tif`` per item, uint8 cover percentages (0-100).

``python -m data_gen.standins LAYOUT ROOT --count N [--seed S]`` writes one.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import tifffile
from PIL import Image

from data_gen.makers.procedural import ProceduralMaker
from synthesis.errors import PatternshopError, run_module_cli
from synthesis.labmap import LabMap

LAYOUTS = ("faces", "animals", "churches", "folder", "treecover")
FACE_PARTS = ("skin", "hair", "cloth", "neck")
ANIMAL_CLASSES = ("cat", "dog", "wild")


def _grey(density: np.ndarray) -> np.ndarray:
    """(H, W) uint8 sRGB grey whose CIELAB lightness is 100 (1 - density)."""
    lab = np.stack([100.0 * (1.0 - density), np.zeros_like(density), np.zeros_like(density)], -1)
    return np.rint(LabMap(lab).to_srgb()[..., 0] * 255).clip(0, 255).astype(np.uint8)


def write_standin(layout: str, root: str | Path, count: int, seed: int = 7, size: int = 256) -> Path:
    """Write ``count`` items of ``layout`` under ``root`` (see the module docstring); returns ``root``."""
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    root = Path(root)
    maker = ProceduralMaker(size)
    for k in range(count):
        _, density, labels = maker.picture(k, np.random.default_rng([seed, k]))
        grey = _grey(density)
        if layout == "faces":
            (root / "CelebA-HQ-img").mkdir(parents=True, exist_ok=True)
            Image.fromarray(grey).save(root / "CelebA-HQ-img" / f"{k}.jpg", quality=95)
            masks = root / "CelebAMask-HQ-mask-anno" / str(k // 2000)
            masks.mkdir(parents=True, exist_ok=True)
            values, counts = np.unique(labels, return_counts=True)
            for part, value in zip(FACE_PARTS, values[np.argsort(-counts)][1:], strict=False):  # largest region: background
                Image.fromarray(np.where(labels == value, 255, 0).astype(np.uint8)).save(masks / f"{k:05d}_{part}.png")
        elif layout == "animals":
            folder = root / "train" / ANIMAL_CLASSES[k % len(ANIMAL_CLASSES)]
            folder.mkdir(parents=True, exist_ok=True)
            Image.fromarray(grey).save(folder / f"{k:05d}.png")
        elif layout in ("churches", "folder"):
            root.mkdir(parents=True, exist_ok=True)
            Image.fromarray(grey).save(root / f"{k:05d}.jpg", quality=95)
        else:
            root.mkdir(parents=True, exist_ok=True)
            tifffile.imwrite(root / f"tile-{k:05d}.tif", np.rint(100.0 * density).astype(np.uint8))
    return root


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m data_gen.standins", description=__doc__.split("\n\n")[0])
    parser.add_argument("layout", choices=LAYOUTS)
    parser.add_argument("root", help="folder to write (created)")
    parser.add_argument("--count", type=int, default=8, help="items (default 8)")
    parser.add_argument("--seed", type=int, default=7, help="picture seed (default 7)")
    parser.add_argument("--size", type=int, default=256, help="picture side in pixels (default 256)")

    def run(args: argparse.Namespace) -> None:
        if args.count < 1 or args.size < 8:
            raise PatternshopError("--count must be >= 1 and --size >= 8")
        print(write_standin(args.layout, args.root, args.count, args.seed, args.size))

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
