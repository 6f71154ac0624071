"""Training pairs for the network: ``python -m data_gen.pairs dataset=procedural num_items=2000``.

Pairs are made in reverse (SPEC §2.4): a dataset's maker draws the target
map (:mod:`data_gen.makers`), the map is quantised to 8 bits (what is stored
is exactly what was synthesised), the synthesiser places
``n = points_per_ink * mean density`` points on it, and the points are
rasterised by :func:`synthesis.raster.point_raster`, the function inference
uses too. Pairs go to compressed shards of ``chunk`` items with a manifest
(:mod:`data_gen.shards`).

* Resumable: a finished item is written at once (``parts/``), a shard as soon
  as all its items are done; a rerun skips both. A bad source is recorded as
  skipped (with the reason) and never retried or fatal.
* Sharded for clusters: ``shard=i num_shards=N`` makes the shard files whose
  number is i modulo N; every machine writes into the same folder (or copy
  the files together), and each run rebuilds the manifest from the shards present.
* On a Dask cluster: ``executor=dask scheduler=tcp://host:8786`` (no address:
  a LocalCluster of ``workers`` processes) sends the items to its workers
  (:mod:`data_gen.executor`), which write their parts into ``out_dir`` (a
  folder they all see at the same path, or an fsspec URL: ``s3://bucket/pairs``
  with s3fs installed, :mod:`data_gen.storage`); this process merges the
  shards. An item whose worker died twice is recorded as skipped with Dask's reason.
* Deterministic: item i uses the random stream ``(seed, i)``, whatever the
  number of workers or shards.
* Other methods: with ``other_methods.share`` > 0, that share of
  the items takes its points from another stippler or reference process
  (:mod:`data_gen.stipplers`: density-proportional Poisson, weighted Lloyd,
  variable-radius Poisson-disk, warped jitter, Thomas clusters, drawn by
  ``other_methods.methods`` weights) applied to the map's density, and its
  a, b become the method's preset colour (:data:`data_gen.stipplers.LABELS`)
  of the pairs' palette, so the network does not learn the synthesiser's
  fingerprint. At share 0 (the default) the items and the config key are those
  of a pair folder made without this option.
* Light and empty content: with ``sparse.share`` > 0, that share of
  the maps has its density multiplied by a factor drawn log-uniformly in
  ``sparse.scale`` and up to ``sparse.holes`` empty discs cut out of it; with
  ``sparse.empty_share`` > 0, that share of the items is empty (no points, a
  white map). Both at 0 (the default): items and config key unchanged.
  With ``sparse.lighten_synthesis: false`` the factor applies only to other methods' items (their labels are
  measured from their points); the synthesiser's items keep their density (holes are still cut): lightened
  x0.03-0.4 to a few dozen points it cannot realise its label's correlation (networks v6 and v6c, trained on
  such items of the v5 recipe, read light Poisson points as bluish). Default true: items and key unchanged.
* Textures: with ``textures.share`` > 0, that share of the maps has its density
  replaced by a procedural texture with fine detail (:mod:`data_gen.makers.textures`:
  fractal and Gabor noise, hatching, Worley cells, rendered text, line art; weights
  ``textures.kinds``), the correlation field kept. At 0 (the default): items and
  config key unchanged. The other methods' labels are what the shipped palette decodes
  from their points (:data:`data_gen.stipplers.LABELS`); the frozen test set's stipplers
  (:data:`data_gen.stipplers.FROZEN_METHODS`) are refused.
* Scale: with ``scale.share`` > 0, that share of the items is made at a points per ink drawn
  log-uniformly in ``scale.points_per_ink`` [lo, hi] (recorded in the item's meta) and labelled at the
  pairs' ``synthesis.points_per_ink`` P, the scale the network reads at: above P the map's content
  is zoomed by ``sqrt(ppi / P)`` (a random window upsampled; ``infer`` draws such a pattern that many times
  larger), below P its density is multiplied by ``ppi / P`` (how the points of a light area at P look, the
  same spacing; ``infer`` read light areas at up to 64 times fewer points per ink). Items and key unchanged at 0.
  With ``scale.lighten_synthesis: false`` only other methods' items are lightened (their labels are measured
  from their points); the synthesiser's are drawn at P instead, since with a few dozen points it cannot realise
  the correlation its label asks for (network v6 read light Poisson points as blue). Default true: key unchanged.
* Dark content: with ``dense.share`` > 0, that share of the other
  maps is darkened towards full ink, ``1 - density`` multiplied by a factor
  drawn log-uniformly in ``dense.scale``, so that nearly full ink, rare in the
  procedural pictures, is seen. At 0 (the default): items and config key unchanged.

Settings: ``conf/pairs.yaml`` and ``conf/dataset/*.yaml``; any value can be
overridden (``workers=2 synthesis.points_per_ink=50000 out_dir=/data/pairs``).
"""

from __future__ import annotations

import functools
import hashlib
import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from data_gen.executor import Executor, Lost
from data_gen.makers import MapMaker, SourceError, build_maker
from data_gen.provenance import file_sha256, git_commit, machine, run_config_command, utc_now
from data_gen.storage import StoragePath, as_path, is_local, write_text_atomic
from data_gen.shards import PARTS, Pairs, map_to_target, part_path, read_manifest, read_shard, shard_path, target_to_map, write_manifest
from synthesis.errors import PatternshopError
from synthesis.labmap import LabMap

FORMAT = 1  # pair folder layout (data_gen.shards); bump when it changes


@dataclass(frozen=True)
class PairSettings:
    """Everything that determines the pairs' contents (and the folder's config key)."""

    dataset: dict
    seed: int
    map_size: int
    raster_size: int
    chunk: int
    points_per_ink: float
    schedule: str
    iterations: int | None
    palette: str | None  # None: the shipped palette
    other_methods: dict  # {"share": float in [0, 1], "methods": {name: weight}} (see the module docstring)
    sparse: dict  # {"share", "scale": [lo, hi], "holes", "empty_share", "lighten_synthesis"} (see the module docstring)
    dense: dict  # {"share", "scale": [lo, hi]} (see the module docstring)
    textures: dict  # {"share", "kinds": {name: weight}} (see the module docstring)
    scale: dict  # {"share", "points_per_ink": [lo, hi], "lighten_synthesis"} (see the module docstring)

    @classmethod
    def from_config(cls, cfg) -> PairSettings:  # noqa: ANN001 - omegaconf.DictConfig
        from omegaconf import OmegaConf

        try:
            return cls(dataset=OmegaConf.to_container(cfg.dataset, resolve=True), seed=int(cfg.seed), map_size=int(cfg.map_size),
                       raster_size=int(cfg.raster_size), chunk=int(cfg.chunk), points_per_ink=float(cfg.synthesis.points_per_ink),
                       schedule=str(cfg.synthesis.schedule), iterations=cfg.synthesis.iterations, palette=cfg.palette,
                       other_methods=other_methods_setting(OmegaConf.to_container(cfg.get("other_methods") or {}, resolve=True)),
                       sparse=sparse_setting(OmegaConf.to_container(cfg.get("sparse") or {}, resolve=True)),
                       dense=dense_setting(OmegaConf.to_container(cfg.get("dense") or {}, resolve=True)),
                       textures=textures_setting(OmegaConf.to_container(cfg.get("textures") or {}, resolve=True)),
                       scale=scale_setting(OmegaConf.to_container(cfg.get("scale") or {}, resolve=True)))
        except (TypeError, ValueError) as exc:  # e.g. map_size=big: a user error, one line like the others
            raise PatternshopError(f"bad pair setting: {exc}") from exc

    def palette_file(self) -> Path:
        from synthesis.palette import DEFAULT_PALETTE

        return Path(self.palette) if self.palette else DEFAULT_PALETTE

    def key(self) -> str:
        """Short hash of the settings and the palette file's contents."""
        content = {"format": FORMAT, **asdict(self), "palette": file_sha256(self.palette_file())}
        content["dataset"] = {k: v for k, v in self.dataset.items() if k != "items"}  # only bounds how many
        if not self.other_methods["share"]:  # folders made before these options keep their key
            del content["other_methods"]
        else:  # a method of weight 0 is never drawn (numpy's choice skips zero-width entries): not part of the key
            content["other_methods"] = {**self.other_methods,
                                        "methods": {k: v for k, v in self.other_methods["methods"].items() if v}}
        if not self.textures["share"]:
            del content["textures"]
        if not self.scale["share"]:
            del content["scale"]
        elif self.scale["lighten_synthesis"]:  # folders made before this option keep their key
            content["scale"] = {k: v for k, v in self.scale.items() if k != "lighten_synthesis"}
        if not (self.sparse["share"] or self.sparse["empty_share"]):
            del content["sparse"]
        elif self.sparse["lighten_synthesis"]:  # folders made before this option keep their key
            content["sparse"] = {k: v for k, v in self.sparse.items() if k != "lighten_synthesis"}
        if not self.dense["share"]:
            del content["dense"]
        return hashlib.sha256(json.dumps(content, sort_keys=True, default=str).encode()).hexdigest()[:16]


def other_methods_setting(config: dict) -> dict:
    """``other_methods`` config -> {"share", "methods"} checked: share in [0, 1], known methods with weights >= 0."""
    from data_gen.stipplers import DEFAULT_METHODS, FROZEN_METHODS, LABELS

    share = float(config.get("share", 0.0))
    methods = {str(name): float(weight) for name, weight in (config.get("methods") or {name: 1.0 for name in DEFAULT_METHODS}).items()}
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"other_methods.share must be in [0, 1], got {share:g}")
    frozen = sorted(set(methods) & set(FROZEN_METHODS))
    if frozen:
        raise ValueError(f"other_methods.methods {frozen} belong to the frozen test set (docs/evaluation.md): never trained on")
    unknown = sorted(set(methods) - set(LABELS))
    if unknown:
        raise ValueError(f"unknown other_methods.methods {unknown}; choose from {', '.join(LABELS)}")
    if share and (min(methods.values(), default=0.0) < 0 or sum(methods.values()) <= 0):
        raise ValueError("other_methods.methods needs weights >= 0 with a positive sum")
    return {"share": share, "methods": methods}


def factor_range(config: dict, name: str, default: tuple[float, float]) -> list[float]:
    """``name.scale`` [lo, hi] of a config block, checked: 0 < lo <= hi <= 1."""
    low, high = (float(value) for value in config.get("scale", default))
    if not 0.0 < low <= high <= 1.0:
        raise ValueError(f"{name}.scale needs 0 < lo <= hi <= 1, got [{low:g}, {high:g}]")
    return [low, high]


def log_uniform_factor(rng: np.random.Generator, bounds: list[float]) -> float:
    """A factor drawn log-uniformly in ``bounds`` [lo, hi] (one draw from ``rng``)."""
    low, high = bounds
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def sparse_setting(config: dict) -> dict:
    """``sparse`` config -> {"share", "scale", "holes", "empty_share", "lighten_synthesis"} checked (shares in [0, 1],
    0 < lo <= hi <= 1)."""
    share, empty_share = float(config.get("share", 0.0)), float(config.get("empty_share", 0.0))
    holes = int(config.get("holes", 3))
    if not (0.0 <= share <= 1.0 and 0.0 <= empty_share <= 1.0):
        raise ValueError(f"sparse.share and sparse.empty_share must be in [0, 1], got {share:g} and {empty_share:g}")
    if holes < 0:
        raise ValueError(f"sparse.holes must be >= 0, got {holes}")
    return {"share": share, "scale": factor_range(config, "sparse", (0.03, 0.4)), "holes": holes, "empty_share": empty_share,
            "lighten_synthesis": bool(config.get("lighten_synthesis", True))}


def textures_setting(config: dict) -> dict:
    """``textures`` config -> {"share", "kinds"} checked (share in [0, 1]; kinds of :data:`data_gen.makers.textures.TEXTURES`)."""
    from data_gen.makers.textures import DEFAULT_TEXTURES, check_kinds

    share = float(config.get("share", 0.0))
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"textures.share must be in [0, 1], got {share:g}")
    return {"share": share, "kinds": check_kinds(config.get("kinds") or DEFAULT_TEXTURES)}


def texture_variant(settings: PairSettings, lab_map: LabMap, rng: np.random.Generator) -> LabMap:
    """The map with its density replaced by a procedural texture (:mod:`data_gen.makers.textures`) for a
    ``textures.share`` of the items, its correlation field kept. Draws from ``rng`` only when the share is > 0."""
    share = settings.textures["share"]
    if not share or rng.random() >= share:
        return lab_map
    from data_gen.makers.textures import texture_picture

    rows, columns = lab_map.L.shape
    density = texture_picture(max(rows, columns), rng, settings.textures["kinds"])[1][:rows, :columns]
    return target_to_map(map_to_target(LabMap.from_density_latent(density, lab_map.latent())))  # 8-bit, as stored


def scale_setting(config: dict) -> dict:
    """``scale`` config -> {"share", "points_per_ink": [lo, hi], "lighten_synthesis"} checked (share in [0, 1], 0 < lo <= hi)."""
    share = float(config.get("share", 0.0))
    low, high = (float(value) for value in config.get("points_per_ink", (125.0, 512000.0)))
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"scale.share must be in [0, 1], got {share:g}")
    if not 0.0 < low <= high:
        raise ValueError(f"scale.points_per_ink needs 0 < lo <= hi, got [{low:g}, {high:g}]")
    return {"share": share, "points_per_ink": [low, high], "lighten_synthesis": bool(config.get("lighten_synthesis", True))}


def zoom_window(lab: np.ndarray, zoom: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) window of ``lab`` (H, W, 3), ``1 / zoom`` of its size at a random offset, bilinearly upsampled
    back to (H, W) (``zoom`` >= 1; pixel centres aligned)."""
    from scipy.ndimage import map_coordinates

    rows, cols = lab.shape[:2]
    top, left = rng.random(2) * (np.array([rows, cols]) * (1.0 - 1.0 / zoom))
    grid_r, grid_c = np.meshgrid(top - 0.5 + (np.arange(rows) + 0.5) / zoom, left - 0.5 + (np.arange(cols) + 0.5) / zoom,
                                 indexing="ij")
    return np.stack([map_coordinates(lab[..., k], [grid_r, grid_c], order=1, mode="nearest") for k in range(3)], -1)


def scale_variant(settings: PairSettings, lab_map: LabMap, rng: np.random.Generator,
                  lighten: bool = True) -> tuple[LabMap, float]:
    """(map, points per ink the item is drawn at): for a ``scale.share`` of the items a points per ink drawn
    log-uniformly in ``scale.points_per_ink``, the map zoomed above ``synthesis.points_per_ink`` and lightened
    below it (see the module docstring); otherwise, or below it with ``lighten`` false, the map and
    ``synthesis.points_per_ink``. Draws from ``rng`` only when the share is > 0."""
    share, base = settings.scale["share"], settings.points_per_ink
    if not share or rng.random() >= share:
        return lab_map, base
    drawn = log_uniform_factor(rng, settings.scale["points_per_ink"])
    if drawn < base and not lighten:
        return lab_map, base
    if drawn >= base:
        lab = zoom_window(np.asarray(lab_map.lab, np.float64), float(np.sqrt(drawn / base)), rng)
        scaled = LabMap(lab.astype(np.float32))
    else:
        scaled = LabMap.from_density_latent(lab_map.density() * (drawn / base), lab_map.latent())
    return target_to_map(map_to_target(scaled)), drawn  # 8-bit, as stored


def dense_setting(config: dict) -> dict:
    """``dense`` config -> {"share", "scale"} checked (share in [0, 1], 0 < lo <= hi <= 1)."""
    share = float(config.get("share", 0.0))
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"dense.share must be in [0, 1], got {share:g}")
    return {"share": share, "scale": factor_range(config, "dense", (0.05, 0.5))}


def density_variant(settings: PairSettings, lab_map: LabMap, rng: np.random.Generator, lighten: bool = True) -> LabMap:
    """The map, lightened and holed for a share of the items (only holed with ``lighten`` false: the factor is
    drawn and not applied), emptied for another, darkened for a third (see the module docstring).

    Draws from ``rng`` only when ``sparse.share``, ``sparse.empty_share`` or ``dense.share`` is > 0.
    """
    options = settings.sparse
    density = None
    if options["empty_share"] and rng.random() < options["empty_share"]:
        density = np.zeros(lab_map.L.shape)
    elif options["share"] and rng.random() < options["share"]:
        factor = log_uniform_factor(rng, options["scale"])
        density = lab_map.density() * (factor if lighten else 1.0)
        rows, cols = np.indices(density.shape)
        for _ in range(int(rng.integers(0, options["holes"] + 1))):
            (row, col), radius = rng.random(2) * density.shape, rng.uniform(0.05, 0.25) * max(density.shape)
            density[(rows - row) ** 2 + (cols - col) ** 2 < radius**2] = 0.0
    elif settings.dense["share"] and rng.random() < settings.dense["share"]:
        density = 1.0 - (1.0 - lab_map.density()) * log_uniform_factor(rng, settings.dense["scale"])
    if density is None:
        return lab_map
    return target_to_map(map_to_target(LabMap.from_density_latent(density, lab_map.latent())))  # 8-bit, as stored


def draw_other(settings: PairSettings, rng: np.random.Generator) -> bool:
    """Whether an item is drawn as another method's (an ``other_methods.share`` of them); draws only when the share is > 0."""
    share = settings.other_methods["share"]
    return bool(share) and rng.random() < share


def other_method_points(settings: PairSettings, maker: MapMaker, lab_map: LabMap, n: int, rng: np.random.Generator,
                        chosen: bool | None = None) -> tuple[LabMap, np.ndarray, str] | None:
    """(map with the method's preset a, b, its points (n, 2), method name) for an item drawn as another method's, else None.

    ``chosen``: :func:`draw_other`'s answer when drawn before, else drawn here. Draws from ``rng`` only when
    ``other_methods.share`` > 0, so the items of share-0 folders are unchanged.
    """
    from data_gen.stipplers import FROZEN_METHODS, LABELS, METHODS

    weights = settings.other_methods["methods"]
    if not (draw_other(settings, rng) if chosen is None else chosen):
        return None
    from data_gen.makers.textures import choose

    method = choose(rng, weights)
    if method in FROZEN_METHODS:  # never reached through other_methods_setting; a guard for hand-made settings
        raise PatternshopError(f"{method} is a frozen test-set stippler (docs/evaluation.md): never trained on")
    label = LABELS[method]  # a preset name, or the (a, b) the shipped palette decodes from the method's points
    a, b = maker.palette.preset_ab()[label] if isinstance(label, str) else label
    lab = np.array(lab_map.lab)
    lab[..., 1:] = (a, b)
    labelled = target_to_map(map_to_target(LabMap(lab)))  # 8-bit, as the stored target
    return labelled, METHODS[method](labelled.density(), n, labelled.domain, rng), method


def item_map(settings: PairSettings, maker: MapMaker, item: int) -> tuple[np.random.Generator, LabMap, float, bool | None]:
    """(item's random stream after the map's draws, its map with every variant applied, the points per ink it is
    drawn at, whether it was drawn as another method's: None when not drawn yet). The first steps of :func:`make_pair`;
    :mod:`data_gen.clean_pairs` replays them."""
    rng = np.random.default_rng([settings.seed, item])
    lab_map = texture_variant(settings, target_to_map(map_to_target(maker.make(item, rng))), rng)
    measured_only = not (settings.scale["lighten_synthesis"] and settings.sparse["lighten_synthesis"])
    other_first = draw_other(settings, rng) if measured_only else None  # lighten measured labels only
    synthesised = other_first is False
    lab_map, drawn_points_per_ink = scale_variant(settings, lab_map, rng,
                                                  lighten=settings.scale["lighten_synthesis"] or not synthesised)
    lab_map = density_variant(settings, lab_map, rng, lighten=settings.sparse["lighten_synthesis"] or not synthesised)
    return rng, lab_map, drawn_points_per_ink, other_first


def make_pair(settings: PairSettings, maker: MapMaker, item: int) -> Pairs:
    """Pair ``item``: map, synthesised (or other methods') points, raster. Raises :class:`SourceError` for a bad source."""
    from synthesis.raster import point_raster
    from synthesis.synthesize import point_count, synthesize

    rng, lab_map, drawn_points_per_ink, other_first = item_map(settings, maker, item)
    target = map_to_target(lab_map)
    try:
        n = point_count(lab_map, settings.points_per_ink)
    except PatternshopError:  # too little ink for one point: only sparse items get here (makers skip white maps)
        n = 0
    if n == 1:
        raise SourceError(f"{maker.source(item)}: only {n} point(s) at points_per_ink={settings.points_per_ink:g}")
    other = other_method_points(settings, maker, lab_map, n, rng, other_first) if n else None
    if n == 0:  # an empty item (sparse.empty_share, or a map lightened below one point)
        xy = np.zeros((0, 2), np.float32)
        meta = {"item": item, "source": maker.source(item), "n": 0, "method": "empty"}
    elif other is not None:
        lab_map, points, method = other
        target, xy = map_to_target(lab_map), points.astype(np.float32)
        meta = {"item": item, "source": maker.source(item), "n": len(xy), "method": method}
    else:
        synthesis_seed = int(rng.integers(2**31))
        result = synthesize(lab_map, n=n, palette=maker.palette, schedule=settings.schedule,
                            iterations=settings.iterations, seed=synthesis_seed)
        xy = result.points.xy.astype(np.float32)
        meta = {"item": item, "source": maker.source(item), "n": n, "seed": synthesis_seed, "method": "synthesis",
                "final_loss": round(result.final_loss, 6), "seconds": round(result.seconds, 3)}
    if settings.scale["share"]:
        meta["points_per_ink"] = round(drawn_points_per_ink, 1)
    return Pairs(item=np.array([item], np.int64), raster=point_raster(xy, settings.raster_size)[None].astype(np.float16),
                 target=target[None], points=xy, offsets=np.array([0, len(xy)], np.int64), meta=[meta])


# --- workers -------------------------------------------------------------------
_WORKER: dict = {}


def _start_worker(settings: PairSettings, threads: int) -> None:
    import torch

    torch.set_num_threads(threads)
    _WORKER["settings"] = settings
    _WORKER["maker"] = build_maker(settings.dataset, settings.map_size, settings.palette)


def _run_item(out_dir: str, item: int) -> tuple[int, str | None]:
    """Make item ``item`` and write its part file; returns (item, skip reason or None)."""
    settings, maker = _WORKER["settings"], _WORKER["maker"]
    try:
        pair = make_pair(settings, maker, item)
    except SourceError as exc:  # bad source: recorded, never fatal
        return item, skip_item(as_path(out_dir), maker, item, str(exc))
    pair.write(part_path(out_dir, item), compressed=False)
    return item, None


def skip_item(out_dir: StoragePath, maker: MapMaker, item: int, reason: str) -> str:
    """Record item ``item`` as skipped for ``reason`` (its part file ``item-N.skip.json``); returns the reason."""
    write_text_atomic(part_path(out_dir, item, skipped=True),
                      json.dumps({"item": item, "source": maker.source(item), "reason": reason}) + "\n")
    return reason


# --- resumption and merging ----------------------------------------------------
def chunk_items(chunk: int, size: int, total: int) -> range:
    return range(chunk * size, min((chunk + 1) * size, total))


def done_items(out_dir: StoragePath, chunk: int) -> set[int]:
    """Items of ``chunk`` already made or skipped (in its shard file or as parts)."""
    done: set[int] = set()
    path = shard_path(out_dir, chunk)
    if path.exists():
        shard = read_shard(path)
        done |= {int(i) for i in shard.item} | {int(s["item"]) for s in shard.skipped}
    return done


def part_items(out_dir: StoragePath) -> set[int]:
    return {int(p.name[5:12]) for p in (out_dir / PARTS).glob("item-*")}


def merge_chunk(out_dir: StoragePath, chunk: int, items: range) -> None:
    """Write shard ``chunk`` from its existing shard file and part files, then delete the parts."""
    path = shard_path(out_dir, chunk)
    singles, skipped = [], []
    if path.exists():
        old = read_shard(path)
        singles += old.split()
        skipped += old.skipped
    used = []
    for item in items:
        part, skip = part_path(out_dir, item), part_path(out_dir, item, skipped=True)
        if part.exists():
            singles.append(read_shard(part))
            used.append(part)
        elif skip.exists():
            skipped.append(json.loads(skip.read_text()))
            used.append(skip)
    singles.sort(key=lambda pair: int(pair.item[0]))
    skipped.sort(key=lambda entry: int(entry["item"]))
    if singles:
        merged = Pairs.concatenate(singles)
    else:
        merged = Pairs(np.zeros(0, np.int64), np.zeros((0, 1, 1), np.float16), np.zeros((0, 1, 1, 3), np.uint8),
                       np.zeros((0, 2), np.float32), np.zeros(1, np.int64))
    merged.skipped = skipped
    merged.write(path)
    for part in used:
        part.unlink()


def generate(cfg) -> dict:  # noqa: ANN001 - omegaconf.DictConfig
    """Make the missing pairs of this shard of the dataset; returns the run summary (see module docstring)."""
    from omegaconf import OmegaConf

    settings = PairSettings.from_config(cfg)
    maker = build_maker(settings.dataset, settings.map_size, settings.palette)
    if cfg.num_items is not None and int(cfg.num_items) < 1:
        raise PatternshopError(f"num_items must be at least 1, got {cfg.num_items}")
    total = len(maker) if cfg.num_items is None else int(cfg.num_items)
    if maker.finite and total > len(maker):
        print(f"[pairs] {maker.name} has {len(maker)} items; making {len(maker)}, not {total}", file=sys.stderr)
        total = len(maker)
    shard, num_shards = int(cfg.shard), int(cfg.num_shards)
    if num_shards < 1 or not 0 <= shard < num_shards:
        raise PatternshopError(f"shard must be in [0, num_shards), got shard={shard} num_shards={num_shards}")
    out_dir = as_path(cfg.out_dir)
    key = settings.key()
    existing = read_manifest(out_dir)
    if existing is not None and existing.get("config_key") != key:
        raise PatternshopError(f"{out_dir} holds pairs made with other settings (config key {existing.get('config_key')}, "
                               f"now {key}); choose another out_dir or delete it")
    (out_dir / PARTS).mkdir(parents=True, exist_ok=True)

    chunks = [c for c in range(-(-total // settings.chunk)) if c % num_shards == shard]
    parts = part_items(out_dir)
    pending: dict[int, list[int]] = {}
    for c in chunks:
        items = chunk_items(c, settings.chunk, total)
        done = done_items(out_dir, c)
        missing = [i for i in items if i not in done and i not in parts]
        if missing or any(i in parts for i in items):
            pending[c] = missing
    header = {"format": FORMAT, "dataset": maker.name, "config_key": key, "seed": settings.seed,
              "settings": asdict(settings), "config": OmegaConf.to_container(cfg, resolve=True),
              "palette": {"file": str(settings.palette_file()), "sha256": file_sha256(settings.palette_file())},
              "raster": {"function": "synthesis.raster.point_raster", "size": settings.raster_size},
              "unreadable_sources": maker.unreadable, "commit": git_commit(), "machine": machine(), "updated": utc_now()}
    todo = [item for missing in pending.values() for item in missing]
    start = time.perf_counter()
    skipped_now: list[str] = []
    remaining = {c: len(missing) for c, missing in pending.items()}
    for c, count in remaining.items():
        if count == 0:  # only parts left from an interrupted run
            merge_chunk(out_dir, c, chunk_items(c, settings.chunk, total))
    executor = Executor.from_config(cfg)
    with tqdm(total=len(todo), desc=f"pairs ({maker.name}, shard {shard}/{num_shards})", unit="pair", smoothing=0.1) as bar:
        def finished(item: int, reason: str | None) -> None:
            if reason:
                skipped_now.append(reason)
                bar.set_postfix(skipped=len(skipped_now), refresh=False)
            bar.update()
            c = item // settings.chunk
            remaining[c] -= 1
            if remaining[c] == 0:
                merge_chunk(out_dir, c, chunk_items(c, settings.chunk, total))

        import torch

        threads = torch.get_num_threads()
        try:  # one worker works in this process; remote workers need the folder's absolute path
            location = str(out_dir.absolute()) if is_local(out_dir) else str(out_dir)
            for outcome in executor.map_unordered(functools.partial(_run_item, location), todo,
                                                  _start_worker, (settings, int(cfg.threads_per_worker))):
                if isinstance(outcome, Lost):  # its Dask workers died on every try
                    outcome = outcome.task, skip_item(out_dir, maker, outcome.task, f"worker lost: {outcome.error}")
                finished(*outcome)
        finally:  # the caller (e.g. train.py) keeps its own thread count
            torch.set_num_threads(threads)
    seconds = time.perf_counter() - start
    made = len(todo) - len(skipped_now)
    runs = (existing or {}).get("runs", [])
    if todo:  # the history of runs that made pairs here: how long the folder took to make
        runs.append({"started": header["updated"], "shard": f"{shard}/{num_shards}", "made": made, "skipped": len(skipped_now),
                     "seconds": round(seconds, 1), "workers": executor.workers, "executor": executor.describe(),
                     "machine": header["machine"]})
    header["runs"] = runs
    manifest = write_manifest(out_dir, header)
    return {"out_dir": str(out_dir), "dataset": maker.name, "shard": f"{shard}/{num_shards}", "made_now": made,
            "skipped_now": skipped_now, "seconds": round(seconds, 1),
            "pairs_per_minute": round(made * 60 / seconds, 2) if made and seconds > 0 else None,
            "pairs_in_folder": manifest["pairs"], "skipped_in_folder": len(manifest["skipped"]),
            "bytes_per_1000_pairs": manifest["bytes_per_1000_pairs"]}


def main(argv: list[str] | None = None) -> int:
    """Entry point: Hydra overrides; errors are one line (``--debug`` shows the traceback)."""
    return run_config_command("python -m data_gen.pairs", "pairs", __doc__, generate, argv)


if __name__ == "__main__":
    sys.exit(main())
