"""Train a generator's correlation decoder alone: its a, b learn more while its L stays bit for bit.

``python -m patternshop_nn.tune_correlation MODEL.ckpt OUT.ckpt --pairs DIR [DIR ...] [--steps 2000]``

Only ``generator.correlation`` (the decoder of a, b; :class:`~patternshop_nn.networks.DualBranchUNet`) learns; the
encoder, the density decoder, the full-resolution path and the ``l_scale`` head keep their weights, so the map's L
and its predicted Laplace scale are the model's exactly, and so is every figure of L. The decoder's batch-norm
statistics stay as they are (eval mode). The features it reads (its own encoder's where it has one, see
:mod:`patternshop_nn.tune_encoder`) of the first ``shards_per_folder`` shards of each pair folder are computed once,
each raster and its target under one random symmetry of the square (with ``--views 2`` also under that symmetry's
transpose, so the decoder sees every pattern with its rows as columns), and ``val_fraction`` of each folder's pairs
is held out (all views of a pair on the same side). A batch comes from one folder drawn uniformly, so a small folder
(the lattices, the cluster processes) counts as much as a large one. The loss is the L1 of a, b over all pixels, as in
training (:class:`~patternshop_nn.module.Pix2PixModule`); Adam (betas 0.5, 0.999), cosine decay to 0.

The checkpoint it writes (:func:`patternshop_nn.module.save_module_checkpoint`; ``patternshop export`` and
``init_from`` take it) records the held-out mean ``|a, b - target|`` per folder, in ab units (0..255), before and
after. About 0.5 s a step on one thread (256-px pairs), 1.2 GB of features for 13 folders of 4 shards of 32 pairs:
not resumable, rerun it.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from tqdm import tqdm

from patternshop_nn.short_training import add_shards_option, add_training_options, training_parser, tune_from_folders
from synthesis.errors import PatternshopError, run_module_cli

if TYPE_CHECKING:  # importing the module pulls in Lightning
    from patternshop_nn.module import Pix2PixModule


@dataclass(frozen=True)
class TuneSettings:
    """The decoder's training (defaults: trial v19's first candidate, corrA, ``docs/network.md``); ``views``: 1 (a
    random symmetry per pair) or 2 (that symmetry and its transpose)."""

    steps: int = 2000
    batch_size: int = 8
    lr: float = 1e-4
    shards_per_folder: int = 4
    val_fraction: float = 0.125
    seed: int = 0
    views: int = 1


@dataclass
class FolderFeatures:
    """One pair folder's cached inputs (``name``: its path as given): the encoder's features (one (N, C_k, S_k, S_k) float16 tensor per level, first
    level first), the a, b targets (N, 2, S, S) float16 in [0, 1] (z = (ab + 128) / 255), held-out and training indices; N counts views
    (pairs × ``TuneSettings.views``)."""

    name: str
    features: list[torch.Tensor]
    targets: torch.Tensor
    held_out: torch.Tensor
    train: torch.Tensor


@torch.no_grad()
def folder_features(generator: torch.nn.Module, folder: str | Path, settings: TuneSettings,
                    generator_rng: torch.Generator, batch_size: int = 8) -> FolderFeatures:
    """The encoder's features and a, b targets of the first ``settings.shards_per_folder`` shards of a pair folder,
    each pair under one random symmetry of the square (:func:`patternshop_nn.data.dihedral`), and with
    ``settings.views`` 2 also under its transpose (a pair's views are consecutive rows)."""
    from data_gen.shards import read_shard, require_shards
    from patternshop_nn.data import dihedral

    if settings.views not in (1, 2):
        raise PatternshopError(f"views must be 1 or 2, got {settings.views}")
    shards = require_shards(folder)[: settings.shards_per_folder]
    levels: list[list[torch.Tensor]] = []
    targets = []
    for shard in shards:
        pairs = read_shard(shard)
        raster = torch.from_numpy(pairs.raster.astype(np.float32))[:, None]
        target = torch.from_numpy(pairs.target[..., 1:].astype(np.float32) / 255.0).permute(0, 3, 1, 2)
        first = torch.randint(8, (len(raster),), generator=generator_rng).tolist()
        codes = [(k, code ^ (4 * view)) for k, code in enumerate(first) for view in range(settings.views)]  # pair-major
        raster = torch.cat([dihedral(raster[k : k + 1], code) for k, code in codes])
        targets.append(torch.cat([dihedral(target[k : k + 1], code) for k, code in codes]).half())
        for start in range(0, len(raster), batch_size):
            levels.append([level.half() for level in generator.correlation_features(raster[start : start + batch_size])])
    targets_all = torch.cat(targets)
    order = torch.randperm(len(targets_all) // settings.views, generator=generator_rng)  # pairs, then their views
    held = max(1, round(settings.val_fraction * len(order)))
    if held >= len(order):
        raise PatternshopError(f"{folder}: {len(order)} pairs leave none to train on after holding {held} out")
    views = (order[:, None] * settings.views + torch.arange(settings.views)).reshape(-1)
    features = [torch.cat(level) for level in zip(*levels, strict=True)]
    return FolderFeatures(str(Path(folder)), features, targets_all, views[: held * settings.views], views[held * settings.views :])


def _ab(generator: torch.nn.Module, data: FolderFeatures, index: torch.Tensor) -> torch.Tensor:
    """(B, 2, S, S) the decoder's a, b (z in [0, 1]) for the cached pairs ``index``."""
    return torch.sigmoid(generator.correlation([level[index].float() for level in data.features]))


@torch.no_grad()
def ab_error(generator: torch.nn.Module, data: FolderFeatures, index: torch.Tensor, batch_size: int = 8) -> float:
    """Mean ``|a, b - target|`` in ab units (0..255) over the pairs ``index`` of a folder."""
    total = 0.0
    for start in range(0, len(index), batch_size):
        part = index[start : start + batch_size]
        total += float((_ab(generator, data, part) - data.targets[part].float()).abs().sum())
    return 255.0 * total / (len(index) * data.targets[0].numel())


def tune_correlation(module: Pix2PixModule, folders: list[FolderFeatures], settings: TuneSettings = TuneSettings(),
                     progress: bool = False) -> dict:
    """Train ``module``'s correlation decoder in place on cached folders (see the module docstring); returns the report:
    per folder the held-out a, b error (ab units) before and after, and the settings."""
    if settings.steps < 1 or settings.batch_size < 1 or not folders:
        raise PatternshopError(f"steps and batch_size must be >= 1 and a folder given, got {settings}, {len(folders)} folders")
    generator = module.generator.eval()
    before = {data.name: round(ab_error(generator, data, data.held_out), 4) for data in folders}
    decoder = generator.correlation  # the only layers between the cached features and the loss: nothing else gets a gradient
    decoder.train()
    for layer in decoder.modules():  # batch-norm statistics as trained
        if isinstance(layer, torch.nn.BatchNorm2d):
            layer.eval()
    rng = torch.Generator().manual_seed(settings.seed)
    optimizer = torch.optim.Adam(decoder.parameters(), lr=settings.lr, betas=(0.5, 0.999))
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, settings.steps)
    for _ in tqdm(range(settings.steps), desc="tune a, b", unit="step", disable=not progress):
        data = folders[int(torch.randint(len(folders), (1,), generator=rng))]
        batch = data.train[torch.randint(len(data.train), (settings.batch_size,), generator=rng)]
        loss = (_ab(generator, data, batch) - data.targets[batch].float()).abs().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
    generator.eval()
    after = {data.name: round(ab_error(generator, data, data.held_out), 4) for data in folders}
    return {"held_out_ab_error_before": before, "held_out_ab_error": after,
            "pairs": {data.name: len(data.targets) for data in folders}, **asdict(settings)}


def main(argv: list[str] | None = None) -> int:
    """Command line: see module docstring; errors are one line on stderr (exit 2)."""
    defaults = TuneSettings()
    parser = training_parser("python -m patternshop_nn.tune_correlation", __doc__, "checkpoint of the generator to tune "
                             "(train.py's last.ckpt, distill's output ...)", "checkpoint to write",
                             "pair folders it learns on, each sampled equally")
    add_shards_option(parser, defaults.shards_per_folder)
    parser.add_argument("--views", type=int, choices=(1, 2), default=defaults.views,
                        help="1: each pair under one random symmetry of the square; 2: also under its transpose, so "
                             "rows read as columns learn the same colour (default %(default)s)")
    add_training_options(parser, defaults, "pairs")

    def run(args: argparse.Namespace) -> None:
        settings = TuneSettings(args.steps, args.batch_size, args.lr, args.shards_per_folder, seed=args.seed, views=args.views)
        tune_from_folders(args, settings, lambda module, folder, rng: folder_features(module.generator.eval(), folder, settings, rng),
                          tune_correlation, "correlation_tuning")

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
