"""Give a generator's correlation decoder an encoder of its own and train the two: a, b learn, L stays bit for bit.

``python -m patternshop_nn.tune_encoder MODEL.ckpt OUT.ckpt --pairs DIR [DIR ...] [--steps 1200]``

:mod:`patternshop_nn.tune_correlation` trains the correlation decoder on the shared encoder's features as they are;
where those features tell two patterns apart only in one orientation (a hexagonal lattice whose rows run along y
read as another pattern than the same lattice with its rows along x), no decoder can learn the colour, and training
the shared encoder moves L (trial v20, ``docs/network.md``). This tool gives the correlation decoder its own encoder
(:meth:`~patternshop_nn.networks.DualBranchUNet.own_correlation_encoder`: a copy of the shared one, so training starts
at the model's function; a model that has one keeps it) and trains that encoder and ``generator.correlation``
together. With ``--shared-levels K`` the own encoder starts from the shared encoder's first K levels (their
features are computed once; they and the skips they feed stay the shared ones), so it costs less. With
``--correlation-stride N`` the correlation decoder stops at 1/N of the raster's side
(:meth:`~patternshop_nn.networks.DualBranchUNet.coarse_correlation_decoder`: its levels down to there kept, a new head
trained at ``--head-lr``, a, b up-sampled bilinearly). The shared encoder, the density decoder, the full-resolution path and the ``l_scale`` head are not on
their path, so L and its Laplace scale are the model's bit for bit. The loss is the L1 of a, b (z in [0, 1])
against the pairs' targets over all pixels, as in training; each batch comes from one folder, drawn uniformly or in
proportion to ``--folder-weights``, each pair under a fresh random symmetry of the square; with ``--edge-weight W`` the
inked pixels within ``--edge-reach-px`` of a correlation edge of the target weigh 1 + W (:func:`edge_mask`: where a
region's colour bleeds into its neighbour's); batch-norm statistics stay as trained (eval mode); Adam (betas
0.5, 0.999), cosine decay to 0. ``val_fraction`` of each folder's pairs is held out; the checkpoint records per
folder the held-out a, b error before and after, in ab units (0..255).

About 0.6-0.7 s a step of 8 256-px pairs on one thread; not resumable, rerun it. The encoder costs 3 % of a 704-px
pass in torch (14 of 469 ms) but about 8 % in ONNX Runtime (a 20,000-point pass 0.119 -> 0.129 s,
``bench/bench_infer.py``, one thread): ``convert`` on two workers 9.06 -> 8.51 files/s beside the shipped model
(trial v21's encF). Sharing the first two levels (trial v21's encG) cut that but lost two stationary rows; the
correlation decoder at S/8 (``--correlation-stride 8``, encI, 6,000 steps at 5.5 a second) made the pass 8.5 %
cheaper than the shipped model's but lost the hexagonal lattice's rotation spread (``docs/network.md``). At S/4 with
the lattice folders weighted 2 it trains at 4-4.5 steps a second: 10,000 steps, then 3,000 more with ``exact-v13``
weighted 4, made model v19 (trial v22: all five stationary processes within 10 ab of ``analyze``; its pass about 6 %
dearer than v18's).
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

from patternshop_nn.networks import decoder_steps
from patternshop_nn.short_training import add_shards_option, add_training_options, training_parser, tune_from_folders
from synthesis.errors import PatternshopError, run_module_cli

if TYPE_CHECKING:  # importing the module pulls in Lightning
    from patternshop_nn.module import Pix2PixModule


@dataclass(frozen=True)
class EncoderSettings:
    """The stage's training (defaults: trial v20's encC and trial v21's encF; encB's lr 1e-4 from v18 lost the
    lattices, ``docs/network.md``)."""

    steps: int = 1200
    batch_size: int = 8
    lr: float = 2e-5
    shards_per_folder: int = 8
    val_fraction: float = 0.125
    seed: int = 0
    folder_weights: tuple[float, ...] | None = None  # one per folder, batches drawn in proportion; None: uniform
    shared_levels: int = 0  # levels the new encoder leaves to the shared one (cheaper); a model with its own keeps it
    correlation_stride: int = 1  # > 1: the correlation decoder stops at S / this, with a new head (cheaper)
    head_lr: float = 1e-3  # Adam's learning rate of that new head (it starts from scratch)
    edge_weight: float = 0.0  # > 0: inked pixels near a correlation edge weigh 1 + this in the loss (see edge_mask)
    edge_reach_px: float = 16.0  # "near": closer than this to the target's nearest correlation edge, raster pixels


@dataclass
class FolderPairs:
    """One pair folder's cached pairs (``name``: its path as given): rasters (N, 1, S, S) float16 (0 or 1), a, b
    targets (N, 2, S, S) float16 in [0, 1] (z = (ab + 128) / 255), held-out and training indices, and with an edge
    weight the pixels it weighs (N, 1, S, S) bool (:func:`edge_mask`; None without)."""

    name: str
    raster: torch.Tensor
    ab: torch.Tensor
    held_out: torch.Tensor
    train: torch.Tensor
    near_edge: torch.Tensor | None = None


def edge_mask(target: np.ndarray, reach_px: float) -> np.ndarray:
    """(N, 1, S, S) bool: the inked pixels (true density >= ``LATENT_MIN_DENSITY``) closer than ``reach_px`` to the
    nearest correlation edge of their target (:func:`patternshop_nn.baselines.correlation_edge_distance`), of pair
    targets (N, S, S, 3) uint8 as stored. There a light region's colour bleeds from its neighbour's (trial v24,
    ``docs/network.md``: held-out a, b error 45 ab within 4 px of an edge against 16 beyond 32 px)."""
    from patternshop_nn.baselines import correlation_edge_distance, inked

    latent = target[..., 1:].transpose(0, 3, 1, 2) / 255.0
    near = np.stack([correlation_edge_distance(z) < reach_px for z in latent])
    return (near & inked(target[..., 0] / 255.0))[:, None]


def folder_pairs(folder: str | Path, settings: EncoderSettings, rng: torch.Generator) -> FolderPairs:
    """The first ``settings.shards_per_folder`` shards of a pair folder, ``settings.val_fraction`` held out."""
    from data_gen.shards import read_shard, require_shards

    rasters, targets, near = [], [], []
    for shard in require_shards(folder)[: settings.shards_per_folder]:
        pairs = read_shard(shard)
        rasters.append(torch.from_numpy(pairs.raster.astype(np.float16))[:, None])
        targets.append(torch.from_numpy(pairs.target[..., 1:]).permute(0, 3, 1, 2).float().div(255.0).half())
        if settings.edge_weight > 0:
            near.append(torch.from_numpy(edge_mask(pairs.target, settings.edge_reach_px)))
    order = torch.randperm(sum(len(r) for r in rasters), generator=rng)
    held = max(1, round(settings.val_fraction * len(order)))
    if held >= len(order):
        raise PatternshopError(f"{folder}: {len(order)} pairs leave none to train on after holding {held} out")
    return FolderPairs(str(Path(folder)), torch.cat(rasters), torch.cat(targets), order[:held], order[held:],
                       torch.cat(near) if near else None)


def _ab_error(generator: torch.nn.Module, data: FolderPairs, index: torch.Tensor, codes: list[int],
              edge_weight: float = 0.0) -> torch.Tensor:
    """Mean |a, b - target| (z units) of the pairs ``index``, each turned by its symmetry ``codes[k]``; with
    ``edge_weight`` > 0 the pixels of ``data.near_edge`` weigh 1 + ``edge_weight`` in the mean."""
    from patternshop_nn.data import dihedral

    def turned(part: torch.Tensor) -> torch.Tensor:
        return torch.cat([dihedral(part[k : k + 1].float(), code) for k, code in zip(index.tolist(), codes, strict=True)])

    error = (torch.sigmoid(generator.correlation_logits(turned(data.raster))) - turned(data.ab)).abs()
    if edge_weight <= 0:
        return error.mean()
    weight = 1.0 + edge_weight * turned(data.near_edge)
    return (error * weight).sum() / (weight.sum() * error.shape[1])


@torch.no_grad()
def held_out_ab_error(generator: torch.nn.Module, data: FolderPairs, batch_size: int = 8) -> float:
    """Mean |a, b - target| in ab units (0..255) over the held-out pairs, as they are."""
    total = 0.0
    for start in range(0, len(data.held_out), batch_size):
        part = data.held_out[start : start + batch_size]
        total += float(_ab_error(generator, data, part, [0] * len(part))) * len(part)
    return 255.0 * total / len(data.held_out)


def tune_encoder(module: Pix2PixModule, folders: list[FolderPairs], settings: EncoderSettings = EncoderSettings(),
                 progress: bool = False) -> dict:
    """Give ``module``'s correlation decoder its own encoder (when it has none) and train the two in place (see the
    module docstring); returns the report: per folder the held-out a, b error (ab units) before and after."""
    if settings.steps < 1 or settings.batch_size < 1 or not folders:
        raise PatternshopError(f"steps and batch_size must be >= 1 and a folder given, got {settings}, {len(folders)} folders")
    if not 0 <= settings.shared_levels < module.generator.levels:
        raise PatternshopError(f"--shared-levels must be in 0 .. {module.generator.levels - 1}, got {settings.shared_levels}")
    try:  # checked before any work; coarse_correlation_decoder below checks it again as it builds the decoder
        decoder_steps(settings.correlation_stride, module.generator.levels)
    except ValueError as exc:
        raise PatternshopError(f"--correlation-stride: {exc}") from exc
    weights = settings.folder_weights
    if settings.edge_weight < 0 or settings.edge_reach_px <= 0 or \
            (settings.edge_weight > 0 and any(data.near_edge is None for data in folders)):
        raise PatternshopError(f"--edge-weight must be >= 0 and --edge-reach-px > 0 (folders cached with the weight), "
                               f"got {settings.edge_weight}, {settings.edge_reach_px}")
    if weights is not None and (len(weights) != len(folders) or min(weights) < 0 or sum(weights) <= 0):
        raise PatternshopError(f"--folder-weights needs one weight >= 0 per folder ({len(folders)}), not all 0; got {list(weights)}")
    generator = module.generator.eval()  # batch-norm statistics and dropout as trained throughout
    generator.own_correlation_encoder(settings.shared_levels)
    module.hparams["correlation_encoder"] = True  # the checkpoint rebuilds the encoder
    module.hparams["correlation_shared_levels"] = generator.correlation_encoder.shared_levels
    before = {data.name: round(held_out_ab_error(generator, data), 4) for data in folders}
    new_head = generator.correlation.stride != settings.correlation_stride
    try:
        generator.coarse_correlation_decoder(settings.correlation_stride)
    except ValueError as exc:
        raise PatternshopError(f"--correlation-stride {settings.correlation_stride}: {exc}") from exc
    module.hparams["correlation_stride"] = generator.correlation.stride
    trained = [*generator.correlation_encoder.parameters(), *generator.correlation.parameters()]  # all on the a, b path
    for parameter in generator.parameters():  # the shared levels' features need no gradient
        parameter.requires_grad_(False)
    for parameter in trained:
        parameter.requires_grad_(True)
    rng = torch.Generator().manual_seed(settings.seed)
    head = {id(p) for p in generator.correlation.head.parameters()} if new_head else set()
    groups = [{"params": [p for p in trained if id(p) not in head]}]
    if head:  # the new head starts from scratch: its own, larger rate
        groups.append({"params": list(generator.correlation.head.parameters()), "lr": settings.head_lr})
    optimizer = torch.optim.Adam(groups, lr=settings.lr, betas=(0.5, 0.999))
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, settings.steps)
    for _ in tqdm(range(settings.steps), desc="tune a, b encoder", unit="step", disable=not progress):
        drawn = torch.randint(len(folders), (1,), generator=rng) if weights is None else \
            torch.multinomial(torch.tensor(weights, dtype=torch.float64), 1, generator=rng)
        data = folders[int(drawn)]
        batch = data.train[torch.randint(len(data.train), (settings.batch_size,), generator=rng)]
        loss = _ab_error(generator, data, batch, torch.randint(8, (settings.batch_size,), generator=rng).tolist(),
                         settings.edge_weight)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
    after = {data.name: round(held_out_ab_error(generator, data), 4) for data in folders}
    return {"held_out_ab_error_before": before, "held_out_ab_error": after,
            "pairs": {data.name: len(data.raster) for data in folders}, **asdict(settings)}


def main(argv: list[str] | None = None) -> int:
    """Command line: see module docstring; errors are one line on stderr (exit 2)."""
    defaults = EncoderSettings()
    parser = training_parser("python -m patternshop_nn.tune_encoder", __doc__, "checkpoint of the generator to tune",
                             "checkpoint to write", "pair folders it learns on, each sampled equally")
    add_shards_option(parser, defaults.shards_per_folder)
    add_training_options(parser, defaults, "pairs")
    parser.add_argument("--folder-weights", type=float, nargs="+", metavar="W",
                        help="one weight per --pairs folder, in order: batches come from a folder in proportion to its "
                             "weight (default: every folder equally)")
    parser.add_argument("--correlation-stride", type=int, default=defaults.correlation_stride, metavar="N",
                        help="stop the correlation decoder at 1/N of the raster's side (a power of 2) with a new head, "
                             "its a, b up-sampled bilinearly: a cheaper pass (default 1: full resolution)")
    parser.add_argument("--head-lr", type=float, default=defaults.head_lr,
                        help=f"learning rate of that new head (default {defaults.head_lr:g})")
    parser.add_argument("--edge-weight", type=float, default=defaults.edge_weight, metavar="W",
                        help="inked pixels closer than --edge-reach-px to a correlation edge of the target weigh 1 + W "
                             "in the loss, where a region's colour bleeds into its neighbour's (default 0: all alike)")
    parser.add_argument("--edge-reach-px", type=float, default=defaults.edge_reach_px, metavar="PX",
                        help=f"how near to an edge, in raster pixels (default {defaults.edge_reach_px:g})")
    parser.add_argument("--shared-levels", type=int, default=defaults.shared_levels,
                        help="encoder levels the correlation decoder keeps sharing with the density decoder; its own "
                             "encoder starts after them and costs less (default 0: all its own)")

    def run(args: argparse.Namespace) -> None:
        weights = tuple(args.folder_weights) if args.folder_weights else None
        settings = EncoderSettings(args.steps, args.batch_size, args.lr, args.shards_per_folder, seed=args.seed,
                                   folder_weights=weights, shared_levels=args.shared_levels,
                                   correlation_stride=args.correlation_stride, head_lr=args.head_lr,
                                   edge_weight=args.edge_weight, edge_reach_px=args.edge_reach_px)
        tune_from_folders(args, settings, lambda module, folder, rng: folder_pairs(folder, settings, rng), tune_encoder,
                          "encoder_tuning")

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
