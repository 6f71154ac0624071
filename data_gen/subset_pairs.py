"""A subset of a pair folder: ``python -m data_gen.subset_pairs SRC DST [--first-shards N] [--min-ink X] [--keep N --seed S]``.

The shipped model's lineage (patternshop_nn/assets/MODEL_CARD.md) trained on parts of folders: the first 7 shards of
``light2-v7b`` (``--first-shards 7``) and a third of ``lattices-v7`` without its lightest items (``--min-ink 0.05
--keep 533 --seed 11``). In that order: the first shards (SRC's shard files in name order), then the items whose mean
density (1 − mean L/255 of the stored target) is at least ``--min-ink``, then ``--keep`` of those drawn without
replacement by ``numpy.random.default_rng(seed).choice``. DST gets the kept items in SRC's shard files and SRC's
manifest header with ``subset`` (source, rule, counts).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from data_gen.clean_pairs import COMPUTED
from data_gen.shards import MANIFEST, Pairs, list_shards, read_manifest, read_shard, write_manifest
from synthesis.errors import PatternshopError


def mean_ink(target: np.ndarray) -> float:
    """Mean density in [0, 1] of a stored target (H, W, 3) uint8 (L in channel 0, 0..255)."""
    return 1.0 - float(target[..., 0].astype(np.float64).mean()) / 255.0


def chosen_items(source: Path, first_shards: int | None, min_ink: float, keep: int | None, seed: int) -> tuple[set[int], dict]:
    """(the item numbers kept, counts) under the rule of the module docstring."""
    shards = list_shards(source)[:first_shards]
    items = [(int(single.item[0]), mean_ink(single.target[0])) for path in shards for single in read_shard(path).split()]
    inked = [item for item, ink in items if ink >= min_ink]
    if keep is not None and keep < len(inked):
        inked = [inked[i] for i in sorted(np.random.default_rng(seed).choice(len(inked), size=keep, replace=False))]
    return set(inked), {"shards": len(shards), "items": len(items),
                        "below_min_ink": sum(ink < min_ink for _, ink in items), "kept": len(inked)}


def subset(source: Path, destination: Path, first_shards: int | None = None, min_ink: float = 0.0,
           keep: int | None = None, seed: int = 0) -> dict:
    """Write ``destination`` from ``source`` (see the module docstring); returns the ``subset`` record."""
    manifest = read_manifest(source)
    if manifest is None:
        raise PatternshopError(f"{source}: no manifest.json (not a pair folder)")
    if destination.exists() and ((destination / MANIFEST).exists() or list_shards(destination)):
        raise PatternshopError(f"{destination}: not empty; give a new folder")
    chosen, counts = chosen_items(source, first_shards, min_ink, keep, seed)
    destination.mkdir(parents=True, exist_ok=True)
    for path in list_shards(source)[:first_shards]:
        shard = read_shard(path)
        kept = [single for single in shard.split() if int(single.item[0]) in chosen]
        if kept:
            part = Pairs.concatenate(kept)
            part.skipped = shard.skipped
            part.write(destination / path.name)
    record = {"source": str(source), "first_shards": first_shards, "min_ink": min_ink, "keep": keep, "seed": seed, **counts}
    write_manifest(destination, {**{k: v for k, v in manifest.items() if k not in COMPUTED}, "subset": record})
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m data_gen.subset_pairs", description=__doc__.split("\n\n")[0])
    parser.add_argument("source", type=Path, help="pair folder with a manifest.json")
    parser.add_argument("destination", type=Path, help="new folder for the kept pairs")
    parser.add_argument("--first-shards", type=int, default=None, metavar="N", help="only SRC's first N shard files")
    parser.add_argument("--min-ink", type=float, default=0.0, metavar="X", help="drop items of mean density below X")
    parser.add_argument("--keep", type=int, default=None, metavar="N", help="then keep N of them, drawn at random")
    parser.add_argument("--seed", type=int, default=0, help="numpy seed of that draw (default 0)")
    args = parser.parse_args(argv)
    try:
        record = subset(args.source, args.destination, args.first_shards, args.min_ink, args.keep, args.seed)
    except PatternshopError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"[subset] {args.destination}: kept {record['kept']} of {record['items']} items "
          f"({record['below_min_ink']} below --min-ink)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
