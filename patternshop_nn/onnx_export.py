"""Export the points-to-map generator to ONNX, with the metadata inference needs.

The exported graph (opset :data:`OPSET`) has one input ``raster``, shape
(B, 1, H, W) float32 in [0, 1] (:func:`synthesis.raster.point_raster`), and
one output ``map``, shape (B, 3, H, W) float32 in [0, 1]: channel 0 is
L/100 (density ``1 - L/100``), channels 1-2 the correlation latent z
(``a, b = 255 z - 128``). All of B, H and W are dynamic (H and W multiples of
64): the network was trained on 256 x 256 rasters, and inference feeds larger
ones for denser patterns (:mod:`export.runtime`). A generator with an
uncertainty head (``l_scale=True``) has a second output
:data:`export.runtime.L_SCALE_NAME` (``l_scale``), shape (B, 1, H, W) float32 > 0: the Laplace scale ``b`` of channel 0,
i.e. the expected absolute error of the density (1 - L/100), in density units
(0..1); the metadata's ``outputs`` names both.

The model's ``metadata_props`` hold, each value JSON-encoded:

* ``patternshop_format``, ``patternshop_version``, ``exported``: this exporter;
* ``palette_sha256``, ``palette_format``: the palette whose latent the map's
  a, b refer to (default: the shipped one; the training pairs' manifest knows
  which one they used, see :func:`metadata_from_pairs`);
* ``raster_function``, ``raster_size``, and ``points_per_ink`` when known: how
  the input is made and the point count of a fully dark unit square in training;
* ``generator``: class, levels and parameter count of the network;
* ``outputs``: each output's name and meaning (``map``, and ``l_scale`` when present);
* any model-card fields the caller passes (name, dataset, description, ...).

Nearest up-sampling and its convolution are exported fused
(:func:`patternshop_nn.networks.fuse_upsampling`: the same function at 2.25
times fewer multiply-adds); :func:`max_abs_difference` compares the exported
graph with the unfused generator.
"""

from __future__ import annotations

import copy
import json
import os
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from data_gen.provenance import file_sha256, utc_now
from export.runtime import INPUT_NAME, L_SCALE_NAME, OUTPUT_NAME, OnnxModel
from patternshop_nn.networks import WithScale, fuse_upsampling
from synthesis.atomic import atomic_path
from synthesis.errors import PatternshopError
from synthesis.palette import DEFAULT_PALETTE, FORMAT_VERSION
from synthesis.raster import RASTER_SIZE
from synthesis.version import package_version

OPSET = 17
FORMAT = 1  # layout of the metadata below; bump when it changes
RASTER_FUNCTION = "synthesis.raster.point_raster"
EXPORTER_KEYS = ("patternshop_format", "patternshop_version", "exported", "raster_function", "raster_size", "generator", "outputs")
OUTPUT_MEANINGS = {OUTPUT_NAME: "(B, 3, H, W) in [0, 1]: L/100, z_a, z_b",
                   L_SCALE_NAME: "(B, 1, H, W) > 0: Laplace scale b of L/100, the expected |error| of the density (0..1 units)"}

PathLike = str | os.PathLike


def load_generator(checkpoint_or_module: PathLike | nn.Module) -> nn.Module:
    """The generator of a Lightning checkpoint (``Pix2PixModule``), of a module with ``.generator``, or the module itself.

    Raises:
        PatternshopError: the checkpoint is missing or not a ``Pix2PixModule`` checkpoint.
    """
    if isinstance(checkpoint_or_module, nn.Module):
        return getattr(checkpoint_or_module, "generator", checkpoint_or_module)
    return load_module(checkpoint_or_module).generator


def load_module(checkpoint: PathLike) -> nn.Module:
    """The ``Pix2PixModule`` of a Lightning checkpoint, on the CPU.

    Raises:
        PatternshopError: the checkpoint is missing or not a ``Pix2PixModule`` checkpoint.
    """
    import pickle

    from patternshop_nn.module import Pix2PixModule

    path = Path(checkpoint)
    if not path.is_file():
        raise PatternshopError(f"{path}: no such checkpoint")
    with open(path, "rb") as handle:
        if handle.read(4) != b"PK\x03\x04":  # torch.save writes a zip archive; torch.load would give advice on weights_only
            raise PatternshopError(f"{path}: not a Pix2PixModule checkpoint (a Lightning .ckpt is a zip archive written by torch.save)")
    try:
        return Pix2PixModule.load_from_checkpoint(path, map_location="cpu")
    except (pickle.UnpicklingError, KeyError, RuntimeError, EOFError, ValueError, TypeError, AttributeError) as exc:
        reason = str(exc).strip().split("\n")[0][:200]  # torch's messages run over many lines of advice
        raise PatternshopError(f"{path}: not a Pix2PixModule checkpoint ({type(exc).__name__}: {reason})") from exc


def metadata_from_pairs(pairs_dir: PathLike) -> dict:
    """Model-card fields from a training-pair folder's manifest: dataset, pair count, points_per_ink, palette.

    Raises:
        PatternshopError: no manifest, or its raster is not the one the exporter fixes.
    """
    from data_gen.shards import MANIFEST, read_manifest

    manifest = read_manifest(pairs_dir)
    if manifest is None:
        raise PatternshopError(f"{pairs_dir}: no {MANIFEST} (not a training-pair folder of 'python -m data_gen.pairs')")
    raster = manifest["raster"]
    if raster != {"function": RASTER_FUNCTION, "size": RASTER_SIZE}:
        raise PatternshopError(f"{pairs_dir}: pairs rasterised by {raster}, the exporter needs {RASTER_FUNCTION} at {RASTER_SIZE} px")
    return {"dataset": manifest["dataset"], "training_pairs": manifest["pairs"], "pairs_config_key": manifest["config_key"],
            "points_per_ink": manifest["settings"]["points_per_ink"], "palette_sha256": manifest["palette"]["sha256"]}


def export_onnx(checkpoint_or_module: PathLike | nn.Module, path: PathLike, metadata: dict | None = None, fuse: bool = True,
                l_scale: bool = True) -> dict:
    """Export the generator to ONNX at ``path`` (atomically) and return the metadata written.

    Args:
        checkpoint_or_module: a ``Pix2PixModule`` checkpoint, a ``Pix2PixModule`` or the generator itself.
        path: output ``.onnx`` file.
        metadata: model-card fields (JSON-serialisable values), e.g. ``points_per_ink``,
            ``dataset``, ``name``, ``description``; ``palette_sha256`` and ``palette_format``
            override the shipped palette's. The keys in :data:`EXPORTER_KEYS` are the exporter's.
        fuse: export nearest up-sampling fused (:func:`patternshop_nn.networks.fuse_upsampling`); False keeps
            the training graph (for comparisons).
        l_scale: export the uncertainty head's ``l_scale`` output when the generator has one (False: ``map`` only,
            the one-output graph of older models).

    Raises:
        PatternshopError: unreadable checkpoint, or metadata that sets an exporter key.
    """
    metadata = dict(metadata or {})
    taken = sorted(set(metadata) & set(EXPORTER_KEYS))
    if taken:
        raise PatternshopError(f"metadata keys {taken} are set by the exporter")
    generator = copy.deepcopy(load_generator(checkpoint_or_module)).eval()
    parameters = sum(p.numel() for p in generator.parameters())  # the trained net's (fusing turns its up-convolutions into buffers)
    if fuse:
        fuse_upsampling(generator)
    outputs = [OUTPUT_NAME, L_SCALE_NAME] if l_scale and getattr(generator, "l_scale", False) else [OUTPUT_NAME]
    props = {"palette_sha256": file_sha256(DEFAULT_PALETTE), "palette_format": FORMAT_VERSION, **metadata,
             "patternshop_format": FORMAT, "patternshop_version": package_version(), "exported": utc_now(),
             "raster_function": RASTER_FUNCTION, "raster_size": RASTER_SIZE,
             "generator": {"class": type(generator).__name__, "levels": getattr(generator, "levels", None),
                           "upsample": getattr(generator, "upsample", None),
                           "parameters": parameters},
             "outputs": {name: OUTPUT_MEANINGS[name] for name in outputs}}
    example = torch.zeros(1, 1, RASTER_SIZE, RASTER_SIZE)
    with atomic_path(path) as tmp:
        with warnings.catch_warnings(), torch.no_grad():
            # the legacy (TorchScript) exporter is deprecated but traces this plain CNN exactly; the
            # generator's Python shape check is not part of the graph (OnnxModel.predict checks shapes)
            warnings.filterwarnings("ignore", category=torch.jit.TracerWarning)
            warnings.filterwarnings("ignore", category=DeprecationWarning)
            torch.onnx.export(WithScale(generator) if len(outputs) > 1 else generator, (example,), str(tmp),
                              input_names=[INPUT_NAME], output_names=outputs, opset_version=OPSET, dynamo=False,
                              dynamic_axes={name: {0: "batch", 2: "height", 3: "width"} for name in (INPUT_NAME, *outputs)})
        model = onnx.load(str(tmp))
        onnx.helper.set_model_props(model, {key: json.dumps(value) for key, value in props.items()})
        onnx.checker.check_model(model, full_check=True)
        onnx.save(model, str(tmp))
    return props


def max_abs_difference(checkpoint_or_module: PathLike | nn.Module, onnx_path: PathLike, rasters: np.ndarray, threads: int = 1) -> float:
    """Largest |torch - ONNX Runtime| over the outputs for rasters (B, 1, H, W) float32 in [0, 1]."""
    generator = copy.deepcopy(load_generator(checkpoint_or_module)).eval()
    rasters = np.ascontiguousarray(rasters, dtype=np.float32)
    with torch.no_grad():
        expected = generator(torch.from_numpy(rasters)).numpy()
    actual = OnnxModel(onnx_path, threads=threads).predict(rasters)
    return float(np.abs(actual - expected).max())
