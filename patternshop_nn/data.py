"""Training data for the network: pair folders (:mod:`data_gen.shards`) as tensors.

A sample is ``(raster, target)``: raster (1, S, S) float32 in [0, 1], target
(3, S, S) float32 in [0, 1] (L/100 and the latent z). Training samples get a
random symmetry of the square (flips and transposition, 8 in all): density and
correlation are isotropic, so each symmetric pair is as valid as the original.
They may also be random ``crop`` x ``crop`` windows: the U-Net is fully
convolutional, density and correlation are local, and a 128-pixel crop costs a
quarter of a full raster, so a CPU sees four times as many pairs per hour.

The validation split is fixed by item number (every ``round(1/val_fraction)``-th
item), so it stays the same when more pairs are added to the folder. Extra
folders (``extra_pairs_dirs``, e.g. other methods' stipplings made with another
seed) add training pairs only: validation and its baselines stay those of
``pairs_dir``, so runs with and without them compare on the same pairs.
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from data_gen.shards import Pairs, load_pairs
from data_gen.storage import as_path
from patternshop_nn.baselines import cached_baselines
from synthesis.errors import PatternshopError


def dihedral(tensor: torch.Tensor, code: int) -> torch.Tensor:
    """One of the 8 symmetries of the square on the last two axes: bit 0 flips x, bit 1 flips y, bit 2 transposes."""
    if code & 1:
        tensor = tensor.flip(-1)
    if code & 2:
        tensor = tensor.flip(-2)
    if code & 4:
        tensor = tensor.transpose(-1, -2)
    return tensor


class PairDataset(Dataset):
    """Samples ``k`` of ``pairs`` (all when ``indices`` is None), optionally with random crops and symmetries.

    Randomness comes from torch's global generator, which ``L.seed_everything(seed, workers=True)`` seeds
    differently in each data-loader worker (a private generator would repeat the same crops in every worker).
    """

    def __init__(self, pairs: Pairs, indices: np.ndarray | None = None, augment: bool = False, crop: int | None = None) -> None:
        self.pairs = pairs
        self.indices = np.arange(len(pairs)) if indices is None else np.asarray(indices)
        self.augment = augment
        side = pairs.raster.shape[-1]
        if crop is not None and not 0 < crop <= side:
            raise ValueError(f"crop must be in (0, {side}], got {crop}")
        self.crop = None if crop in (None, side) else crop

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        k = int(self.indices[index])
        raster = torch.from_numpy(self.pairs.raster[k].astype(np.float32))[None]
        target = torch.from_numpy(self.pairs.target[k]).permute(2, 0, 1).float() / 255.0
        if self.crop:
            top, left = (int(v) for v in torch.randint(raster.shape[-1] - self.crop + 1, (2,)))
            raster = raster[..., top : top + self.crop, left : left + self.crop]
            target = target[..., top : top + self.crop, left : left + self.crop]
        if self.augment:
            code = int(torch.randint(8, (1,)))
            raster, target = dihedral(raster, code), dihedral(target, code)
        return raster.contiguous(), target.contiguous()


def split_items(items: np.ndarray, val_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """(train, val) positions: every round(1/val_fraction)-th item number goes to validation."""
    if not 0 < val_fraction < 1:
        raise ValueError(f"val_fraction must be in (0, 1), got {val_fraction}")
    stride = max(2, round(1 / val_fraction))
    is_val = np.asarray(items) % stride == stride - 1
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


class PairDataModule(L.LightningDataModule):
    """Train/validation loaders over a pair folder and optional training-only extra folders (loaded into memory:
    ~330 kB per 256 x 256 pair)."""

    def __init__(self, pairs_dir: str | Path, batch_size: int = 8, val_fraction: float = 0.05, augment: bool = True, crop: int | None = None,
                 num_workers: int = 0, max_val_items: int | None = 32, baselines: bool = True,
                 baseline_cells: int = 4, extra_pairs_dirs: list[str | Path] | tuple = ()) -> None:
        super().__init__()
        self.pairs_dir = as_path(pairs_dir)  # local folders or fsspec URLs (data_gen.storage)
        self.extra_pairs_dirs = [as_path(folder) for folder in extra_pairs_dirs]
        self.batch_size, self.val_fraction, self.augment, self.crop = batch_size, val_fraction, augment, crop
        self.num_workers, self.max_val_items = num_workers, max_val_items
        self.baselines, self.baseline_cells = baselines, baseline_cells
        self.pairs: Pairs | None = None
        self.baseline_metrics: dict | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.pairs is not None:
            return
        main = load_pairs(self.pairs_dir)
        train, val = split_items(main.item, self.val_fraction)
        if self.max_val_items is not None:
            val = val[: self.max_val_items]
        if len(train) == 0 or len(val) == 0:
            raise PatternshopError(f"{self.pairs_dir}: {len(main)} pairs are too few for a train/validation split "
                                   f"at val_fraction={self.val_fraction}")
        folders = [(self.pairs_dir, main)] + [(folder, load_pairs(folder)) for folder in self.extra_pairs_dirs]
        for folder, pairs in folders:
            if pairs.raster.shape[-1] != pairs.target.shape[-2] or pairs.raster.shape[-1] != main.raster.shape[-1]:
                raise PatternshopError(f"{folder}: rasters are {pairs.raster.shape[-1]} px and maps {pairs.target.shape[-2]} px; "
                                       f"make pairs with map_size = raster_size = {main.raster.shape[-1]}")
        self.pairs = Pairs.concatenate([pairs for _, pairs in folders]) if len(folders) > 1 else main
        train = np.concatenate([train, np.arange(len(main), len(self.pairs))])  # extra folders: training only
        self.train_set = PairDataset(self.pairs, train, augment=self.augment, crop=self.crop)
        self.val_set = PairDataset(self.pairs, val)
        if self.baselines:
            self.baseline_metrics = cached_baselines(self.pairs_dir, self.pairs, val, self.baseline_cells)

    def train_dataloader(self) -> DataLoader:
        return DataLoader(self.train_set, batch_size=self.batch_size, shuffle=True, drop_last=len(self.train_set) > self.batch_size,
                          num_workers=self.num_workers, persistent_workers=self.num_workers > 0)

    def val_dataloader(self) -> DataLoader:
        return DataLoader(self.val_set, batch_size=self.batch_size, shuffle=False, num_workers=self.num_workers,
                          persistent_workers=self.num_workers > 0)
