"""The command line shared by the short trainings of part of a model (``distill``, ``tune_correlation``, ``tune_encoder``)."""

from __future__ import annotations

import argparse
from collections.abc import Callable


def training_parser(prog: str, doc: str, model_help: str, out_help: str, pairs_help: str) -> argparse.ArgumentParser:
    """A parser with the positional ``model`` (a checkpoint) and ``out`` and the required ``--pairs DIR [DIR ...]``;
    its description is the first line of ``doc``."""
    parser = argparse.ArgumentParser(prog=prog, description=doc.splitlines()[0])
    parser.add_argument("model", help=model_help)
    parser.add_argument("out", help=out_help)
    parser.add_argument("--pairs", nargs="+", required=True, help=pairs_help)
    return parser


def add_training_options(parser: argparse.ArgumentParser, defaults: object, unit: str) -> None:
    """``--steps``, ``--batch-size``, ``--lr``, ``--seed`` and ``--threads``, their defaults read from ``defaults``'
    attributes of those names (a settings dataclass); ``unit`` names what a batch holds ("rasters", "pairs")."""
    parser.add_argument("--steps", type=int, default=defaults.steps, help=f"batches (default {defaults.steps})")
    parser.add_argument("--batch-size", type=int, default=defaults.batch_size,
                        help=f"{unit} a batch (default {defaults.batch_size})")
    parser.add_argument("--lr", type=float, default=defaults.lr,
                        help=f"Adam's learning rate, decaying to 0 (default {defaults.lr:g})")
    parser.add_argument("--seed", type=int, default=defaults.seed,
                        help=f"held-out draw, batches and symmetries (default {defaults.seed})")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")


def add_shards_option(parser: argparse.ArgumentParser, default: int) -> None:
    """``--shards-per-folder N``: the first N shards of each pair folder."""
    parser.add_argument("--shards-per-folder", type=int, default=default,
                        help=f"the first N shards of each folder (default {default})")


def tune_from_folders(args: argparse.Namespace, settings: object, cache: Callable, tune: Callable, record: str) -> None:
    """The shared run of a tuning command: check every ``--pairs`` folder before work, load ``args.model``, cache each
    folder (``cache(module, folder, rng)``, one generator seeded ``settings.seed`` for all), ``tune(module, folders,
    settings, progress=True)`` -> report, write ``args.out`` with the report under ``record`` and print the held-out
    a, b error (its ``held_out_ab_error_before`` and ``held_out_ab_error``, per folder) before and after."""
    import numpy as np
    import torch
    from tqdm import tqdm

    from data_gen.shards import require_shards
    from patternshop_nn.module import save_module_checkpoint
    from patternshop_nn.onnx_export import load_module

    torch.set_num_threads(args.threads)
    for folder in args.pairs:  # before any work
        require_shards(folder)
    module = load_module(args.model)  # a missing or foreign file: one line
    rng = torch.Generator().manual_seed(settings.seed)
    folders = [cache(module, folder, rng) for folder in tqdm(args.pairs, desc="folders", unit="folder")]
    report = tune(module, folders, settings, progress=True)
    save_module_checkpoint(module, args.out, tuned_from=args.model, **{record: {**report, "folders": args.pairs}})
    before, after = report["held_out_ab_error_before"], report["held_out_ab_error"]
    print(f"wrote {args.out}: held-out |a, b - target| {np.mean(list(after.values())):.3f} ab units on average over "
          f"{len(after)} folders (before {np.mean(list(before.values())):.3f})")
