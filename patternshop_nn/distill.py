"""Distil a generator's full-resolution path into a cheaper one on K x K blocks (``model.full_res_stride``).

``python -m patternshop_nn.distill TEACHER.ckpt OUT.ckpt --pairs DIR [DIR ...] [--channels 16 --stride 4]``

The student is the teacher with its full-resolution path replaced by one on ``K x K`` blocks
(:class:`~patternshop_nn.networks.DualBranchUNet`, ``full_res_stride``), started at zero. Every other weight is the
teacher's and stays fixed, so the map's a, b and the predicted Laplace scale are the teacher's exactly, and so is
the decoder's L logit ``l``; only the path learns. Its loss is the mean absolute difference between the student's L
and the teacher's, ``sigmoid(l + correction)`` (L/100), on rasters of pair folders (the first ``rasters_per_folder``
of each, ``val_fraction`` of them drawn and held out). ``l`` and the teacher's L are computed once, in one pass of
the teacher; the path then trains on batches of them under random symmetries of the square (Adam, cosine decay to 0).

The checkpoint it writes (:func:`patternshop_nn.module.save_module_checkpoint`; ``patternshop export`` and
``init_from`` take it) records the held-out mean ``|L_student - L_teacher|`` in L units (0..100) before (no path)
and after. A few minutes on one thread: not resumable, rerun it.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from tqdm import tqdm

from patternshop_nn.short_training import add_training_options, training_parser
from synthesis.errors import PatternshopError, run_module_cli

if TYPE_CHECKING:  # importing the module pulls in Lightning
    from patternshop_nn.module import Pix2PixModule


@dataclass(frozen=True)
class DistillSettings:
    """The student's path and its training (defaults: what made v18, ``docs/network.md``, "Model v18")."""

    channels: int = 16  # the student path's channels
    stride: int = 4  # its block side K (model.full_res_stride)
    steps: int = 3000
    batch_size: int = 16
    lr: float = 1e-3
    val_fraction: float = 0.125
    seed: int = 0


def student_of(teacher: Pix2PixModule, channels: int, stride: int) -> Pix2PixModule:
    """The teacher's module (eval mode) with its full-resolution path replaced by a zero one of ``channels`` on
    ``stride`` x ``stride`` blocks; every other weight copied."""
    from patternshop_nn.module import Pix2PixModule
    from patternshop_nn.networks import DualBranchUNet

    if teacher.generator.full_res_channels <= 0:
        raise PatternshopError("the teacher has no full-resolution path to distil (model.full_res_channels is 0)")
    student = Pix2PixModule(**{**teacher.hparams, "full_res_channels": channels, "full_res_stride": stride})
    path = tuple(f"generator.{name}." for name in DualBranchUNet.FULL_RES_MODULES)
    student.load_state_dict({k: v for k, v in teacher.state_dict().items() if not k.startswith(path)}, strict=False)
    student.generator.zero_refinement()
    return student.eval()


@torch.no_grad()
def teacher_readings(generator: torch.nn.Module, rasters: torch.Tensor, batch_size: int = 8) -> tuple[torch.Tensor, torch.Tensor]:
    """(decoder's L logit (N, 1, S, S), the generator's L/100 (N, 1, S, S) in [0, 1]) of rasters (N, 1, S, S)."""
    logits, lightness = [], []
    for start in range(0, len(rasters), batch_size):
        raster = rasters[start : start + batch_size]
        logit = generator.density(generator._encode(raster))
        logits.append(logit)
        lightness.append(torch.sigmoid(generator._refined(raster, logit)))
    return torch.cat(logits), torch.cat(lightness)


@torch.no_grad()
def l_error(generator: torch.nn.Module, rasters: torch.Tensor, logits: torch.Tensor, lightness: torch.Tensor,
            batch_size: int = 16) -> float:
    """Mean ``|L - L_target|`` in L units (0..100) of ``generator``'s path on the given logits."""
    total = 0.0
    for start in range(0, len(rasters), batch_size):
        part = slice(start, start + batch_size)
        total += float((torch.sigmoid(generator._refined(rasters[part], logits[part])) - lightness[part]).abs().sum())
    return 100.0 * total / lightness.numel()


def distill_path(teacher: Pix2PixModule, rasters: torch.Tensor, settings: DistillSettings = DistillSettings(),
                 progress: bool = False) -> tuple[Pix2PixModule, dict]:
    """(student module, report): the teacher's path distilled into ``settings``' on rasters (N, 1, S, S) in [0, 1]
    (see the module docstring); the report holds the held-out L errors (L units) before and after, and the settings."""
    from patternshop_nn.data import dihedral

    if not 0.0 < settings.val_fraction < 1.0 or settings.steps < 1 or settings.batch_size < 1:
        raise PatternshopError(f"val_fraction must be in (0, 1), steps and batch_size >= 1, got {settings}")
    generator = torch.Generator().manual_seed(settings.seed)
    order = torch.randperm(len(rasters), generator=generator)
    held = max(1, round(settings.val_fraction * len(rasters)))
    if held >= len(rasters):
        raise PatternshopError(f"{len(rasters)} rasters leave none to train on after holding {held} out")
    teacher = teacher.eval()
    student = student_of(teacher, settings.channels, settings.stride)
    logits, lightness = teacher_readings(teacher.generator, rasters)
    val, train = order[:held], order[held:]
    path = student.generator
    before = l_error(path, rasters[val], logits[val], lightness[val])
    optimizer = torch.optim.Adam(path.full_res_parameters(), lr=settings.lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, settings.steps)
    for _ in tqdm(range(settings.steps), desc="distil", unit="step", disable=not progress):
        batch = train[torch.randint(len(train), (settings.batch_size,), generator=generator)]
        code = int(torch.randint(8, (1,), generator=generator))
        raster, logit, target = (dihedral(tensor[batch], code) for tensor in (rasters, logits, lightness))
        loss = (torch.sigmoid(path._refined(raster, logit)) - target).abs().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
    after = l_error(path, rasters[val], logits[val], lightness[val])
    report = {"rasters": len(rasters), "held_out": held, "held_out_l_error_without_path": round(before, 4),
              "held_out_l_error": round(after, 4), **asdict(settings)}
    return student, report


def folder_rasters(folders: list[str], per_folder: int) -> torch.Tensor:
    """(N, 1, S, S) float32: the first ``per_folder`` rasters of each pair folder, read shard by shard."""
    from data_gen.shards import read_shard, require_shards

    parts = []
    for folder in folders:
        count = 0
        for shard in require_shards(folder):
            if count >= per_folder:
                break
            raster = read_shard(shard).raster[: per_folder - count]
            parts.append(raster.astype(np.float32))
            count += len(raster)
    return torch.from_numpy(np.concatenate(parts))[:, None]


def main(argv: list[str] | None = None) -> int:
    """Command line: see module docstring; errors are one line on stderr (exit 2)."""
    defaults = DistillSettings()
    parser = training_parser("python -m patternshop_nn.distill", __doc__, "the teacher: checkpoint of a generator with a "
                             "full-resolution path (train.py's last.ckpt)", "student checkpoint to write",
                             "pair folders whose rasters it learns on")
    parser.add_argument("--rasters-per-folder", type=int, default=192, help="the first N rasters of each folder (default 192)")
    parser.add_argument("--channels", type=int, default=defaults.channels, help=f"student path's channels (default {defaults.channels})")
    parser.add_argument("--stride", type=int, default=defaults.stride, help=f"its block side K (default {defaults.stride})")
    add_training_options(parser, defaults, "rasters")

    def run(args: argparse.Namespace) -> None:
        from patternshop_nn.onnx_export import load_module

        torch.set_num_threads(args.threads)
        teacher = load_module(args.model)  # a missing or foreign file: one line
        rasters = folder_rasters(args.pairs, args.rasters_per_folder)
        settings = DistillSettings(args.channels, args.stride, args.steps, args.batch_size, args.lr, seed=args.seed)
        try:
            student, report = distill_path(teacher, rasters, settings, progress=True)
        except ValueError as exc:  # a stride the raster side does not allow
            raise PatternshopError(str(exc)) from exc
        from patternshop_nn.module import save_module_checkpoint

        save_module_checkpoint(student, args.out, distilled_from=args.model,
                               distillation={**report, "pairs": args.pairs, "rasters_per_folder": args.rasters_per_folder})
        print(f"wrote {args.out}: held-out |L - teacher's L| {report['held_out_l_error']:.4f} L units "
              f"(without the path {report['held_out_l_error_without_path']:.4f})")

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
