"""Storage of training pairs: compressed shard files, per-item parts, the manifest.

A pair folder holds::

    manifest.json              dataset, seed, config, palette, raster, totals, skipped items
    pairs-00000.npz            items [0, chunk), compressed
    pairs-00001.npz            items [chunk, 2 chunk) ...
    parts/item-0000042.npz     a finished item whose shard is not complete yet
    parts/item-0000043.skip.json   a skipped item (bad source) and why

Shard arrays (K pairs; S raster size, H = W map size):

* ``raster`` (K, S, S) float16 in [0, 1] — the network input (:func:`synthesis.raster.point_raster`).
* ``target`` (K, H, W, 3) uint8 — the map, 8-bit: ``round(L * 255 / 100)``,
  ``a + 128``, ``b + 128``; divided by 255 it is the network output
  (L / 100 and the latent z) in [0, 1].
* ``points`` (sum n, 2) float32 and ``offsets`` (K + 1,) int64 — item k's
  points are ``points[offsets[k]:offsets[k + 1]]``.
* ``item`` (K,) int64 and ``meta_json`` (per item: source, n, seed,
  synthesis loss and time; plus the skipped items of the shard).

The folder may be a local path or an fsspec URL (``s3://bucket/pairs``,
:mod:`data_gen.storage`); every file is written atomically.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np

from data_gen.storage import StoragePath, as_path, write_atomic, write_text_atomic
from synthesis.labmap import LabMap

MANIFEST = "manifest.json"
PARTS = "parts"


def map_to_target(lab_map: LabMap) -> np.ndarray:
    """(H, W, 3) uint8 8-bit encoding of a map (see the module docstring)."""
    lab = lab_map.lab.astype(np.float64)
    return np.stack([np.rint(lab[..., 0] * 2.55), np.rint(lab[..., 1]) + 128, np.rint(lab[..., 2]) + 128], -1).clip(0, 255).astype(np.uint8)


def target_to_map(target: np.ndarray) -> LabMap:
    """Inverse of :func:`map_to_target`."""
    target = np.asarray(target, np.float32)
    return LabMap(np.stack([target[..., 0] / 2.55, target[..., 1] - 128, target[..., 2] - 128], -1))


def shard_path(folder: str | os.PathLike, chunk: int) -> StoragePath:
    """Shard ``chunk`` of a pair folder (a local path or an fsspec URL, :func:`data_gen.storage.as_path`)."""
    return as_path(folder) / f"pairs-{chunk:05d}.npz"


def part_path(folder: str | os.PathLike, item: int, skipped: bool = False) -> StoragePath:
    return as_path(folder) / PARTS / (f"item-{item:07d}.skip.json" if skipped else f"item-{item:07d}.npz")


@dataclass
class Pairs:
    """Pairs in memory (one shard or several concatenated)."""

    item: np.ndarray  # (K,) int64
    raster: np.ndarray  # (K, S, S) float16
    target: np.ndarray  # (K, H, W, 3) uint8
    points: np.ndarray  # (sum n, 2) float32
    offsets: np.ndarray  # (K + 1,) int64
    meta: list[dict] = field(default_factory=list)  # one per item
    skipped: list[dict] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.item)

    def points_of(self, k: int) -> np.ndarray:
        """(n, 2) points of pair k, in map units."""
        return self.points[self.offsets[k] : self.offsets[k + 1]]

    @classmethod
    def concatenate(cls, parts: list[Pairs]) -> Pairs:
        """One :class:`Pairs` holding all ``parts`` in the given order.

        Parts without pairs (a shard whose items were all skipped stores (0, 1, 1) placeholder
        arrays) only contribute their skipped lists, so they concatenate with any raster size.
        """
        full = [part for part in parts if len(part)] or parts[:1]
        counts = [np.diff(part.offsets) for part in full]
        return cls(
            item=np.concatenate([part.item for part in full]),
            raster=np.concatenate([part.raster for part in full]),
            target=np.concatenate([part.target for part in full]),
            points=np.concatenate([part.points for part in full]),
            offsets=np.concatenate([[0], np.cumsum(np.concatenate(counts))]).astype(np.int64),
            meta=[m for part in full for m in part.meta],
            skipped=[s for part in parts for s in part.skipped],
        )

    def split(self) -> list[Pairs]:
        """One :class:`Pairs` per item (without the skipped list)."""
        return [Pairs(self.item[k : k + 1], self.raster[k : k + 1], self.target[k : k + 1], self.points_of(k),
                         np.array([0, self.offsets[k + 1] - self.offsets[k]], np.int64), [self.meta[k]], [])
                for k in range(len(self))]

    def write(self, path: str | os.PathLike, compressed: bool = True) -> None:
        """Write as one shard file (a local path or an fsspec URL), atomically."""
        write_atomic(path, lambda handle: (np.savez_compressed if compressed else np.savez)(
            handle, item=self.item, raster=self.raster, target=self.target, points=self.points, offsets=self.offsets,
            meta_json=np.str_(json.dumps({"items": self.meta, "skipped": self.skipped}))))


def read_shard(path: str | os.PathLike) -> Pairs:
    """Read a shard (or part) file (a local path or an fsspec URL)."""
    with as_path(path).open("rb") as handle, np.load(handle, allow_pickle=False) as data:
        meta = json.loads(str(data["meta_json"]))
        return Pairs(item=data["item"].astype(np.int64), raster=data["raster"], target=data["target"], points=data["points"],
                     offsets=data["offsets"].astype(np.int64), meta=meta["items"], skipped=meta["skipped"])


def list_shards(folder: str | os.PathLike) -> list[StoragePath]:
    """Shard files of a pair folder, in item order."""
    return sorted(as_path(folder).glob("pairs-*.npz"), key=lambda path: path.name)


def require_shards(folder: str | os.PathLike) -> list[StoragePath]:
    """:func:`list_shards`, or a :class:`~synthesis.errors.PatternshopError` (one line for the user) when there is none."""
    from synthesis.errors import PatternshopError

    shards = list_shards(folder)
    if not shards:
        raise PatternshopError(f"{folder}: no pair shards (pairs-*.npz); make them with 'python -m data_gen.pairs'")
    return shards


def load_pairs(folder: str | os.PathLike) -> Pairs:
    """Every pair of a folder's shards, in item order (parts of unfinished shards are not included)."""
    return Pairs.concatenate([read_shard(path) for path in require_shards(folder)])


def read_manifest(folder: str | os.PathLike) -> dict | None:
    path = as_path(folder) / MANIFEST
    return json.loads(path.read_text()) if path.is_file() else None


def write_manifest(folder: str | os.PathLike, header: dict) -> dict:
    """Rebuild ``manifest.json`` from ``header`` and every shard present (so shards made elsewhere count too)."""
    folder = as_path(folder)
    shards, skipped, pairs, points, total_bytes = [], [], 0, 0, 0
    for path in list_shards(folder):
        with path.open("rb") as handle, np.load(handle, allow_pickle=False) as data:
            meta = json.loads(str(data["meta_json"]))
        count = len(meta["items"])
        shards.append({"file": path.name, "pairs": count, "skipped": len(meta["skipped"]), "bytes": path.stat().st_size})
        skipped += meta["skipped"]
        pairs += count
        points += sum(int(m["n"]) for m in meta["items"])
        total_bytes += path.stat().st_size
    manifest = dict(header)
    manifest.update({"pairs": pairs, "points": points, "bytes": total_bytes,
                     "bytes_per_1000_pairs": round(total_bytes * 1000 / pairs) if pairs else None,
                     "shards": shards, "skipped": skipped})
    write_text_atomic(folder / MANIFEST, json.dumps(manifest, indent=2) + "\n")
    return manifest
