"""Training-map makers, one module per dataset, chosen by name (SPEC §2.4).

A maker turns item ``i`` of a dataset into a target :class:`~synthesis.labmap.LabMap`
of ``size`` x ``size`` pixels: density from an image's grey levels (or a
procedural picture, or tree-cover percentages) and a random correlation field
(:mod:`data_gen.chroma`). Makers are deterministic given the item's random
generator, so the pair generator can resume and shard.

================  ============================================  ==============================
name              source layout under ``root``                  chroma
================  ============================================  ==============================
``faces``         CelebAMask-HQ: ``CelebA-HQ-img/<id>.jpg``,    two items per image: uniform,
                  ``CelebAMask-HQ-mask-anno/<k>/<id:05d>_       and one latent per segment
                  <part>.png``                                  (groups of parts, background)
``animals``       AFHQ: ``{train,val}/{cat,dog,wild}/*.png``    uniform
``churches``      LSUN churches exported as image files         uniform
``folder``        any folder of images (recursive)              uniform or Gaussian field
``treecover``     Tree Cover Density GeoTIFFs, tiled            uniform or Gaussian field
``procedural``    nothing: pictures drawn from the seed         uniform, segments, Gaussians
``textures``      nothing: procedural textures (fine detail)    uniform or Gaussian field
================  ============================================  ==============================

Use :func:`build_maker` with a dataset config (``conf/dataset/NAME.yaml``).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

from data_gen.makers.base import MapMaker, SourceError

MAKERS = {
    "faces": "data_gen.makers.faces:FacesMaker",
    "animals": "data_gen.makers.animals:AnimalsMaker",
    "churches": "data_gen.makers.folder:ChurchesMaker",
    "folder": "data_gen.makers.folder:FolderMaker",
    "treecover": "data_gen.makers.treecover:TreeCoverMaker",
    "procedural": "data_gen.makers.procedural:ProceduralMaker",
    "textures": "data_gen.makers.textures:TexturesMaker",
}

__all__ = ["MAKERS", "MapMaker", "SourceError", "build_maker"]


def build_maker(config: Mapping[str, Any], size: int, palette: str | None = None) -> MapMaker:
    """The maker named ``config["name"]``, configured by the rest of ``config``, for size x size maps.

    ``palette``: path of the palette whose populated region the chroma is drawn from (default: shipped).
    """
    from synthesis.errors import PatternshopError

    name = config.get("name")
    if name not in MAKERS:
        raise PatternshopError(f"unknown dataset {name!r}; choose one of {', '.join(MAKERS)}")
    module, cls = MAKERS[name].split(":")
    options = {key: value for key, value in config.items() if key != "name"}
    options["palette"] = palette
    return getattr(importlib.import_module(module), cls).from_config(options, size)
