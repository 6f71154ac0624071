"""Drop the pairs whose labels their points cannot show: ``python -m data_gen.clean_pairs SRC DST``.

Pair folders made with ``sparse.lighten_synthesis`` or ``scale.lighten_synthesis`` true (the shipped model v5's
recipe, networks v6 and v6c) hold synthesised items lightened to a few dozen points, whose labels ask for a
correlation those points cannot show; networks trained on them read light Poisson points as bluish
(docs/network.md). This copies SRC to DST without them (other methods' items are kept: their labels are measured
from their points). A synthesised item is dropped when

* its meta says it was drawn below the pairs' points per ink (``scale``), or
* its map was lightened by ``sparse``: the item's draws are replayed (:func:`data_gen.pairs.item_map`, its random
  stream ``(seed, item)``) with the lightening factor fixed at 1 (the same draws); an item whose stored 8-bit
  lightness equals the replay's was not lightened and is kept, one whose density is at most ``sparse.scale``'s
  upper factor times the replay's was lightened. An item matching neither (a maker changed since the folder was
  made) is dropped too and counted as ``unmatched``.

DST gets the kept items in SRC's shard files and SRC's manifest with ``cleaned`` (source, dropped items and why).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from data_gen.makers import MapMaker, build_maker
from data_gen.pairs import PairSettings, item_map
from data_gen.shards import MANIFEST, Pairs, list_shards, map_to_target, read_manifest, read_shard, write_manifest
from synthesis.errors import PatternshopError, run_module_cli

COMPUTED = ("pairs", "points", "bytes", "bytes_per_1000_pairs", "shards", "skipped")  # write_manifest's own fields


def drop_reason(settings: PairSettings, unlit: PairSettings, maker: MapMaker, item: int, meta: dict,
                target: np.ndarray) -> str | None:
    """Why item ``item`` (its ``meta``, stored ``target`` (H, W, 3) uint8) is dropped ("scale", "sparse",
    "unmatched"), or None to keep it. ``unlit``: ``settings`` with the sparse factor fixed at 1."""
    if meta.get("method") != "synthesis":
        return None
    if float(meta.get("points_per_ink", settings.points_per_ink)) < settings.points_per_ink:
        return "scale"
    if not (settings.sparse["share"] or settings.sparse["empty_share"] or settings.dense["share"]):
        return None  # no density variant: nothing to replay
    replay = map_to_target(item_map(unlit, maker, item)[1])[..., 0].astype(np.float64)
    stored = target[..., 0].astype(np.float64)
    if np.array_equal(replay, stored):
        return None
    ink_replay, ink_stored = 1.0 - replay.mean() / 255.0, 1.0 - stored.mean() / 255.0
    return "sparse" if ink_stored <= settings.sparse["scale"][1] * ink_replay + 1.0 / 255.0 else "unmatched"


def clean(source: Path, destination: Path) -> dict:
    """Write ``destination`` from ``source`` without its lightened synthesised items; returns the ``cleaned`` record."""
    manifest = read_manifest(source)
    if manifest is None:
        raise PatternshopError(f"{source}: no manifest.json (its settings are needed to replay the items)")
    settings = PairSettings.from_config(OmegaConf.create(manifest["config"]))
    unlit = dataclasses.replace(settings, sparse={**settings.sparse, "scale": [1.0, 1.0]})
    maker = build_maker(settings.dataset, settings.map_size, settings.palette)
    destination.mkdir(parents=True, exist_ok=True)
    if (destination / MANIFEST).exists() or list_shards(destination):
        raise PatternshopError(f"{destination}: not empty; give a new folder")
    dropped: dict[str, list[int]] = {"scale": [], "sparse": [], "unmatched": []}
    kept = 0
    for path in list_shards(source):
        shard = read_shard(path)
        keep = []
        for single in shard.split():
            reason = drop_reason(settings, unlit, maker, int(single.item[0]), single.meta[0], single.target[0])
            if reason is None:
                keep.append(single)
            else:
                dropped[reason].append(int(single.item[0]))
        if keep:
            part = Pairs.concatenate(keep)
            part.skipped = shard.skipped
            part.write(destination / path.name)
            kept += len(keep)
        print(f"[clean] {path.name}: kept {len(keep)} of {len(shard)}", file=sys.stderr)
    record = {"source": str(source), "kept": kept, "dropped": dropped,
              "rule": "synthesised items lightened by sparse or drawn below synthesis.points_per_ink by scale"}
    header = {k: v for k, v in manifest.items() if k not in COMPUTED}
    write_manifest(destination, {**header, "cleaned": record})
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m data_gen.clean_pairs", description=__doc__.split("\n\n")[0])
    parser.add_argument("source", type=Path, help="pair folder with a manifest.json")
    parser.add_argument("destination", type=Path, help="new folder for the kept pairs")

    def run(args: argparse.Namespace) -> None:
        record = clean(args.source, args.destination)
        counts = {reason: len(items) for reason, items in record["dropped"].items()}
        print(f"[clean] {args.destination}: kept {record['kept']}, dropped {counts}", file=sys.stderr)

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
