"""Training entry point (``python train.py dataset=procedural``; settings in ``conf/train.yaml``).

1. Makes the missing training pairs of the dataset (:func:`data_gen.pairs.generate`,
   resumable) unless ``data.generate=false``.
2. Trains :class:`~patternshop_nn.module.Pix2PixModule` with the Lightning
   Trainer of ``trainer=cpu|gpu|ddp``, checkpointing into ``${run_dir}/checkpoints``
   (``last.ckpt`` every ``checkpoint_every_n_steps`` steps and at epoch ends,
   ``best.ckpt`` by validation L1; with ``keep_epoch_checkpoints=true`` also ``epoch=K.ckpt``
   after every epoch). With ``ema_decay`` (e.g. 0.995) an exponential moving average of the
   weights is kept (Lightning's ``WeightAveraging``): validation, checkpoints' ``state_dict``
   and so the exported model use the averaged weights (the raw ones are kept under
   ``current_model_state`` for resuming). Rerunning the same command resumes from
   ``last.ckpt`` (``resume=false`` starts over). ``init_from=<checkpoint>``
   starts a new run (new optimisers and schedule) from another run's weights:
   a fine-tuning stage, e.g. on whole rasters with a decaying learning rate.
3. Writes ``${run_dir}/summary.json``: steps, epochs, wall time, median
   training-step time, the last validation metrics and the baselines (also
   after Ctrl+C, which stops at the current step; ``last.ckpt`` is at most
   ``checkpoint_every_n_steps`` steps old).

User errors (missing dataset root, too few pairs...) are one line on stderr and
exit status 2; ``HYDRA_FULL_ERROR=1`` or ``+debug=true`` shows the traceback.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

import hydra
import lightning as L
import torch
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from data_gen.provenance import CONF_DIR
from patternshop_nn.networks import DualBranchUNet
from synthesis.errors import PatternshopError


class StepTimer(L.Callback):
    """Wall time of every training batch (both optimiser steps), for the summary."""

    def __init__(self) -> None:
        self.seconds: list[float] = []
        self._start = 0.0

    def on_train_batch_start(self, trainer, module, batch, batch_index) -> None:  # noqa: ANN001 - Lightning's hook
        self._start = time.perf_counter()

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_index) -> None:  # noqa: ANN001
        self.seconds.append(time.perf_counter() - self._start)


class FinalCheckpoint(L.Callback):
    """Writes ``last.ckpt`` when training ends: the every-N-steps ``last.ckpt`` of ``ModelCheckpoint`` lags the
    final weights by up to N - 1 steps when N does not divide the step count (network v7: step 1,600 of 1,680)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def on_train_end(self, trainer, module) -> None:  # noqa: ANN001 - Lightning's hook
        trainer.save_checkpoint(self.path)


def weight_average(decay: float) -> L.Callback:
    """An exponential moving average of all weights and buffers, updated after every batch: ``avg <- decay avg +
    (1 - decay) w``, starting at the weights after the first batch; ``decay`` in (0, 1) (0.995: about the last 200
    batches). Lightning swaps it in for validation, saves it as the checkpoint's ``state_dict`` and leaves it in the
    model when training ends."""
    from lightning.pytorch.callbacks import WeightAveraging
    from torch.optim.swa_utils import get_ema_multi_avg_fn

    if not 0.0 < decay < 1.0:
        raise PatternshopError(f"ema_decay must be between 0 and 1 (exclusive), got {decay:g}")
    return WeightAveraging(multi_avg_fn=get_ema_multi_avg_fn(decay))


def make_pairs(cfg: DictConfig) -> None:
    """Make the missing pairs: ``cfg.pairs`` is conf/generation/default.yaml, as in ``python -m data_gen.pairs``."""
    from data_gen.pairs import generate

    pairs = OmegaConf.create(OmegaConf.to_container(cfg.pairs, resolve=True))
    pairs.dataset = cfg.dataset
    summary = generate(pairs)
    if summary["made_now"] or summary["skipped_now"]:
        print(f"[train] pairs: {json.dumps(summary)}", file=sys.stderr)


def load_weights(model: L.LightningModule, checkpoint: Path) -> None:
    """Generator and discriminator weights of ``checkpoint`` (a Lightning checkpoint of the same architecture, or of
    one without the full-resolution path, which then starts as built: adding zero to L)."""
    if not checkpoint.is_file():
        raise PatternshopError(f"init_from: no such checkpoint {checkpoint}")
    state = torch.load(checkpoint, map_location="cpu", weights_only=False).get("state_dict")
    if state is None:
        raise PatternshopError(f"init_from: {checkpoint} is not a Lightning checkpoint (no state_dict)")
    try:
        keys = model.load_state_dict(state, strict=False)
    except RuntimeError as exc:  # shapes that differ
        raise PatternshopError(f"init_from: {checkpoint} does not fit the configured model ({str(exc).splitlines()[0]})") from exc
    path = tuple(f"generator.{name}." for name in DualBranchUNet.FULL_RES_MODULES)
    missing = [name for name in keys.missing_keys if not name.startswith(path)]
    if missing or keys.unexpected_keys:  # only the full-resolution path may be missing: it starts as built (adding zero to L)
        raise PatternshopError(f"init_from: {checkpoint} does not fit the configured model "
                               f"(missing {missing[:3]}, unexpected {keys.unexpected_keys[:3]})")
    new_path = " (the full-resolution path starts at zero)" if keys.missing_keys else ""
    print(f"[train] weights from {checkpoint}{new_path}", file=sys.stderr)


def train(cfg: DictConfig) -> dict:
    """Run steps 1-3 of the module docstring; returns the summary."""
    from lightning.pytorch.callbacks import ModelCheckpoint

    from patternshop_nn.data import PairDataModule

    averaging = weight_average(float(cfg.ema_decay)) if cfg.get("ema_decay") is not None else None  # checked first
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    if cfg.data.generate and rank_zero_only.rank == 0:  # DDP: the ranks rank 0 starts read what it made before
        make_pairs(cfg)
    L.seed_everything(int(cfg.seed), workers=True, verbose=False)
    run_dir = Path(cfg.run_dir)
    data = cfg.data
    datamodule = PairDataModule(data.pairs_dir, batch_size=int(data.batch_size), val_fraction=float(data.val_fraction),
                                augment=bool(data.augment), crop=data.crop, num_workers=int(data.num_workers),
                                max_val_items=data.max_val_items, baselines=bool(data.baselines),
                                baseline_cells=int(data.baseline_cells), extra_pairs_dirs=list(data.get("extra_pairs_dirs") or ()))
    model = hydra.utils.instantiate(cfg.model, _convert_="all")
    if cfg.get("init_from"):
        load_weights(model, Path(cfg.init_from))
    checkpoints = run_dir / "checkpoints"
    timer = StepTimer()
    callbacks = [
        ModelCheckpoint(dirpath=checkpoints, save_last=True, save_top_k=0, every_n_train_steps=int(cfg.checkpoint_every_n_steps)),
        ModelCheckpoint(dirpath=checkpoints, filename="best", monitor="val/l1", mode="min", save_top_k=1),
        timer,
        FinalCheckpoint(checkpoints / "last.ckpt"),  # before the average is copied into the model at the end
    ]
    if averaging is not None:
        callbacks.append(averaging)
    if cfg.get("keep_epoch_checkpoints"):  # checkpoints/epoch=K.ckpt at every epoch end, all kept (interim models)
        callbacks.append(ModelCheckpoint(dirpath=checkpoints, filename="{epoch}", save_top_k=-1, every_n_epochs=1))
    logger = hydra.utils.instantiate(cfg.logger)
    trainer = hydra.utils.instantiate(cfg.trainer, logger=logger, callbacks=callbacks, default_root_dir=str(run_dir))
    last = checkpoints / "last.ckpt"
    resume_from = str(last) if cfg.resume and last.is_file() else None
    if resume_from:
        print(f"[train] resuming from {last}", file=sys.stderr)
    start = time.perf_counter()
    interrupted = False
    try:
        trainer.fit(model, datamodule=datamodule, ckpt_path=resume_from)
    except SystemExit:  # Lightning's graceful stop on Ctrl+C ends in exit(1): still write the summary
        interrupted = True
    metrics = {key: round(float(value), 6) for key, value in trainer.callback_metrics.items() if key.startswith("val/")}
    summary = {"run_dir": str(run_dir), "resumed_from": resume_from, "init_from": cfg.get("init_from"), "interrupted": interrupted, "global_step": trainer.global_step,
               "epochs": trainer.current_epoch, "world_size": trainer.world_size, "seconds_this_run": round(time.perf_counter() - start, 1),
               "median_step_seconds": round(statistics.median(timer.seconds), 4) if timer.seconds else None,
               "batch_size": int(data.batch_size), "threads": torch.get_num_threads(),
               "train_pairs": len(datamodule.train_set), "val_pairs": len(datamodule.val_set),
               "val_metrics": metrics, "baselines": datamodule.baseline_metrics,
               "checkpoints": {"last": str(last), "best": callbacks[1].best_model_path or None}}
    if not trainer.is_global_zero:  # DDP: one summary, rank 0's
        return summary
    run_dir.mkdir(parents=True, exist_ok=True)
    from synthesis.atomic import atomic_write_text

    atomic_write_text(run_dir / "summary.json", json.dumps(summary, indent=2) + "\n")
    if interrupted:
        print(f"[train] interrupted; rerun the command to resume from {last}", file=sys.stderr)
        sys.exit(130)
    return summary


@hydra.main(config_path=str(CONF_DIR), config_name="train", version_base=None)
def main(cfg: DictConfig) -> None:
    try:
        summary = train(cfg)
    except (PatternshopError, OSError) as exc:
        if cfg.get("debug"):
            raise
        print(f"train.py: error: {exc}", file=sys.stderr)
        sys.exit(2)
    if rank_zero_only.rank == 0:
        print(json.dumps(summary, indent=2))
