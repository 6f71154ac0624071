"""Train a generator's encoder with its correlation decoder: a, b learn what the encoder's features hide, L held to the model's.

``python -m patternshop_nn.tune_encoder MODEL.ckpt OUT.ckpt --pairs DIR [DIR ...] [--steps 1200]``

:mod:`patternshop_nn.tune_correlation` trains the correlation decoder on the encoder's features as they are; where
those features tell two patterns apart only in one orientation (a hexagonal lattice whose rows run along y reads as
another pattern than the same lattice with its rows along x), no decoder can learn the colour. This tool trains the
encoder (``generator.first``, ``generator.downs``) and ``generator.correlation`` together. The density decoder, the
full-resolution path and the ``l_scale`` head keep their weights, and L and its Laplace scale are held to the
starting model's by distillation: the loss is the L1 of a, b against the pairs' targets, plus ``l_weight`` × the
L1 of L against the starting model's L, plus ``scale_weight`` × the L1 of the log scale against the starting
model's (both read once per pair; L/100 and a, b as z in [0, 1]). Each batch comes from one folder drawn uniformly,
each pair under a fresh random symmetry of the square (the starting model's readings turned with it). Batch-norm
statistics stay as trained (eval mode). ``val_fraction`` of each folder's pairs is held out; the checkpoint records
per folder the held-out a, b error before and after, and the held-out L's distance from the starting model's.

About 1.8 s a step of 8 256-px pairs on one thread; not resumable, rerun it.
"""

from __future__ import annotations

import argparse
import copy
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from tqdm import tqdm

from patternshop_nn.short_training import add_shards_option, add_training_options, training_parser
from synthesis.errors import PatternshopError, run_module_cli

if TYPE_CHECKING:  # importing the module pulls in Lightning
    from patternshop_nn.module import Pix2PixModule


@dataclass(frozen=True)
class EncoderSettings:
    """The stage's training (defaults: trial v20's candidate, ``docs/network.md``)."""

    steps: int = 1200
    batch_size: int = 8
    lr: float = 2e-5
    shards_per_folder: int = 8
    val_fraction: float = 0.125
    l_weight: float = 1.0
    scale_weight: float = 0.1
    seed: int = 0


@dataclass
class FolderPairs:
    """One pair folder's cached pairs (``name``: its path as given), all (N, C, S, S) float16: rasters (C 1, 0 or 1),
    a, b targets and the starting model's L/100 (C 2 and 1, in [0, 1]), the starting model's log Laplace scale
    (C 1); held-out and training indices."""

    name: str
    raster: torch.Tensor
    ab: torch.Tensor
    teacher_l: torch.Tensor
    teacher_log_scale: torch.Tensor
    held_out: torch.Tensor
    train: torch.Tensor


@torch.no_grad()
def folder_pairs(generator: torch.nn.Module, folder: str | Path, settings: EncoderSettings,
                 rng: torch.Generator, batch_size: int = 8) -> FolderPairs:
    """The first ``settings.shards_per_folder`` shards of a pair folder with the starting generator's L and scale."""
    from data_gen.shards import read_shard, require_shards

    rasters, targets, levels, scales = [], [], [], []
    for shard in require_shards(folder)[: settings.shards_per_folder]:
        pairs = read_shard(shard)
        raster = torch.from_numpy(pairs.raster.astype(np.float32))[:, None]
        targets.append(torch.from_numpy(pairs.target[..., 1:]).permute(0, 3, 1, 2).float().div(255.0).half())
        rasters.append(raster.half())
        for start in range(0, len(raster), batch_size):
            lab, scale = generator.forward_with_scale(raster[start : start + batch_size])
            levels.append(lab[:, :1].half())
            scales.append(scale.log().half())
    order = torch.randperm(sum(len(r) for r in rasters), generator=rng)
    held = max(1, round(settings.val_fraction * len(order)))
    if held >= len(order):
        raise PatternshopError(f"{folder}: {len(order)} pairs leave none to train on after holding {held} out")
    return FolderPairs(str(Path(folder)), torch.cat(rasters), torch.cat(targets), torch.cat(levels), torch.cat(scales),
                       order[:held], order[held:])


def _batch(data: FolderPairs, index: torch.Tensor, codes: list[int]) -> list[torch.Tensor]:
    """(raster, a b, teacher L, teacher log scale) of the pairs ``index``, each turned by its symmetry ``codes[k]``."""
    from patternshop_nn.data import dihedral

    parts = (data.raster, data.ab, data.teacher_l, data.teacher_log_scale)
    return [torch.cat([dihedral(part[k : k + 1].float(), code) for k, code in zip(index.tolist(), codes, strict=True)])
            for part in parts]


def _losses(generator: torch.nn.Module, data: FolderPairs, index: torch.Tensor, codes: list[int]) -> tuple[torch.Tensor, ...]:
    """(mean |a, b - target|, mean |L - teacher's L|, mean |log b - teacher's|) of a batch, z units."""
    raster, ab, teacher_l, teacher_log_scale = _batch(data, index, codes)
    lab, scale = generator.forward_with_scale(raster)
    return ((lab[:, 1:] - ab).abs().mean(), (lab[:, :1] - teacher_l).abs().mean(),
            (scale.log() - teacher_log_scale).abs().mean())


@torch.no_grad()
def held_out_errors(generator: torch.nn.Module, data: FolderPairs, batch_size: int = 8) -> tuple[float, float]:
    """(mean |a, b - target| in ab units 0..255, mean |L - teacher's L| in L units 0..100) over the held-out pairs."""
    ab_total = l_total = 0.0
    for start in range(0, len(data.held_out), batch_size):
        part = data.held_out[start : start + batch_size]
        ab_error, l_error, _ = _losses(generator, data, part, [0] * len(part))
        ab_total += float(ab_error) * len(part)
        l_total += float(l_error) * len(part)
    count = len(data.held_out)
    return 255.0 * ab_total / count, 100.0 * l_total / count


def tune_encoder(module: Pix2PixModule, folders: list[FolderPairs], settings: EncoderSettings = EncoderSettings(),
                 progress: bool = False) -> dict:
    """Train ``module``'s encoder and correlation decoder in place (see the module docstring); returns the report."""
    if settings.steps < 1 or settings.batch_size < 1 or not folders:
        raise PatternshopError(f"steps and batch_size must be >= 1 and a folder given, got {settings}, {len(folders)} folders")
    generator = module.generator.eval()  # batch-norm statistics and dropout as trained throughout
    before = {data.name: held_out_errors(generator, data) for data in folders}
    trained = [*generator.first.parameters(), *generator.downs.parameters(), *generator.correlation.parameters()]
    frozen = {id(p) for p in trained}
    saved_flags = [(p, p.requires_grad) for p in generator.parameters()]
    for p in generator.parameters():  # the density decoder, the path and the scale head get no gradient
        p.requires_grad_(id(p) in frozen)
    rng = torch.Generator().manual_seed(settings.seed)
    optimizer = torch.optim.Adam(trained, lr=settings.lr, betas=(0.5, 0.999))
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, settings.steps)
    try:
        for _ in tqdm(range(settings.steps), desc="tune encoder", unit="step", disable=not progress):
            data = folders[int(torch.randint(len(folders), (1,), generator=rng))]
            batch = data.train[torch.randint(len(data.train), (settings.batch_size,), generator=rng)]
            codes = torch.randint(8, (settings.batch_size,), generator=rng).tolist()
            ab_loss, l_loss, scale_loss = _losses(generator, data, batch, codes)
            loss = ab_loss + settings.l_weight * l_loss + settings.scale_weight * scale_loss
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()
    finally:
        for p, flag in saved_flags:
            p.requires_grad_(flag)
    after = {data.name: held_out_errors(generator, data) for data in folders}
    return {"held_out_ab_error_before": {name: round(v[0], 4) for name, v in before.items()},
            "held_out_ab_error": {name: round(v[0], 4) for name, v in after.items()},
            "held_out_l_change": {name: round(v[1], 4) for name, v in after.items()},
            "pairs": {data.name: len(data.raster) for data in folders}, **asdict(settings)}


def main(argv: list[str] | None = None) -> int:
    """Command line: see module docstring; errors are one line on stderr (exit 2)."""
    defaults = EncoderSettings()
    parser = training_parser("python -m patternshop_nn.tune_encoder", __doc__, "checkpoint of the generator to tune "
                             "(needs an l_scale head)", "checkpoint to write", "pair folders it learns on, each sampled equally")
    add_shards_option(parser, defaults.shards_per_folder)
    parser.add_argument("--l-weight", type=float, default=defaults.l_weight,
                        help=f"weight of |L - the starting model's L| (default {defaults.l_weight:g})")
    parser.add_argument("--scale-weight", type=float, default=defaults.scale_weight,
                        help=f"weight of |log b - the starting model's| (default {defaults.scale_weight:g})")
    add_training_options(parser, defaults, "pairs")

    def run(args: argparse.Namespace) -> None:
        from data_gen.shards import require_shards
        from patternshop_nn.module import save_module_checkpoint
        from patternshop_nn.onnx_export import load_module

        torch.set_num_threads(args.threads)
        settings = EncoderSettings(args.steps, args.batch_size, args.lr, args.shards_per_folder,
                                   l_weight=args.l_weight, scale_weight=args.scale_weight, seed=args.seed)
        for folder in args.pairs:  # before any work
            require_shards(folder)
        module = load_module(args.model)  # a missing or foreign file: one line
        if not module.generator.l_scale:
            raise PatternshopError(f"{args.model}: the generator has no l_scale head to hold")
        rng = torch.Generator().manual_seed(settings.seed)
        teacher = copy.deepcopy(module.generator).eval()
        folders = [folder_pairs(teacher, folder, settings, rng) for folder in tqdm(args.pairs, desc="pairs", unit="folder")]
        report = tune_encoder(module, folders, settings, progress=True)
        save_module_checkpoint(module, args.out, tuned_from=args.model, encoder_tuning={**report, "folders": args.pairs})
        before, after = report["held_out_ab_error_before"], report["held_out_ab_error"]
        print(f"wrote {args.out}: held-out |a, b - target| {np.mean(list(after.values())):.3f} ab units on average over "
              f"{len(after)} folders (before {np.mean(list(before.values())):.3f}); held-out |L - the model's L| "
              f"{np.mean(list(report['held_out_l_change'].values())):.3f} L units")

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
