"""Training-pair benchmark: throughput, size on disk, quality of the synthesised points.

* Throughput: ``data_gen.pairs.generate`` with 2 workers (1 torch thread each)
  on fresh procedural items, at the default model's count
  (``points_per_ink`` 8,000, 150 iterations) and at the paper's (50,000, the
  synthesiser's full 250 iterations); pairs per minute including the workers'
  start-up, and the minutes a 2,000-pair set takes at that rate. If
  ``data/pairs/procedural`` holds a full set made by ``python -m data_gen.pairs``,
  its recorded runs are reported too (that is the real 2,000-pair time).
* Quality on a sample of procedural maps: the local PCF error (mean over points
  and radii of |edge-aware PCF - target|, the synthesis benchmark's measure)
  and the density SSIM of the points, after 0 (random, density-proportional
  start), 150 (pairs) and 250 (synthesis default) iterations.

Run with ``make bench`` or ``python bench/bench_pairs.py [--quick]``; results in
``out/bench/pairs.json``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from common import save_results  # bench/ is on sys.path when run as a script

from data_gen.makers import build_maker
from data_gen.pairs import generate
from data_gen.provenance import compose_config
from data_gen.shards import map_to_target, read_manifest, target_to_map
from synthesis.edgepcf import local_errors
from synthesis.points import PointSet
from synthesis.synthesize import initial_points, point_count, synthesize
from synthesis.tone import density_fidelity

FULL_SET = Path(__file__).resolve().parent.parent / "data" / "pairs" / "procedural"
HELD_OUT_SEED = 1000  # items of another seed than the training set's (seed 0)


def throughput(points_per_ink: int, iterations: int, items: int) -> dict:
    with tempfile.TemporaryDirectory() as folder:
        cfg = compose_config("pairs", [f"out_dir={folder}", f"num_items={items}", f"seed={HELD_OUT_SEED}", "workers=2",
                                       f"synthesis.points_per_ink={points_per_ink}", f"synthesis.iterations={iterations}"])
        summary = generate(cfg)
    per_minute = summary["pairs_per_minute"]
    return {"points_per_ink": points_per_ink, "iterations": iterations, "pairs": summary["made_now"],
            "seconds": summary["seconds"], "pairs_per_minute": per_minute,
            "minutes_for_2000": round(2000 / per_minute, 1) if per_minute else None,
            "bytes_per_1000_pairs": summary["bytes_per_1000_pairs"]}


def quality(samples: int) -> dict:
    torch.set_num_threads(2)
    cfg = compose_config("pairs", [])
    maker = build_maker(cfg.dataset, int(cfg.map_size))
    rows = {0: [], 150: [], 250: []}
    for item in range(samples):
        rng = np.random.default_rng([HELD_OUT_SEED, item])
        lab_map = target_to_map(map_to_target(maker.make(item, rng)))
        n = point_count(lab_map, float(cfg.synthesis.points_per_ink))
        for iterations in rows:
            start = time.perf_counter()
            if iterations:
                points = synthesize(lab_map, n=n, palette=maker.palette, iterations=iterations, seed=item).points
            else:
                points = PointSet(initial_points(lab_map, n, np.random.default_rng(item)), lab_map.domain)
            seconds = time.perf_counter() - start
            errors, _ = local_errors(lab_map, points.xy, n)
            rows[iterations].append((float(np.mean(errors)), density_fidelity(points, lab_map)["ssim"], seconds))
    table = {}
    for iterations, values in rows.items():
        error, ssim, seconds = np.array(values).T
        table[f"iterations_{iterations}"] = {"local_pcf_error_mean": round(float(error.mean()), 4),
                                             "density_ssim_mean": round(float(ssim.mean()), 4),
                                             "seconds_per_map_2_threads": round(float(np.median(seconds)), 2)}
    return {"maps": samples, "points_per_ink": float(cfg.synthesis.points_per_ink), **table}


def recorded_full_set() -> dict | None:
    manifest = read_manifest(FULL_SET)
    if manifest is None:
        return None
    runs = manifest.get("runs", [])
    return {"folder": str(FULL_SET), "pairs": manifest["pairs"], "skipped": len(manifest["skipped"]),
            "bytes_per_1000_pairs": manifest["bytes_per_1000_pairs"], "runs": runs,
            "recorded_minutes": round(sum(run["seconds"] for run in runs) / 60, 1) if runs else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer pairs and maps (a smoke run)")
    args = parser.parse_args()
    results = {
        "throughput_default": throughput(8000, 150, 6 if args.quick else 20),
        "throughput_paper_count": throughput(50000, 250, 2 if args.quick else 4),
        "quality": quality(2 if args.quick else 6),
        "full_set": recorded_full_set(),
        "target": ">= 2,000 pairs within 90 minutes on 2 cores (minutes_for_2000 <= 90)",
    }
    save_results("pairs", results)
    print(json.dumps({"minutes_for_2000_default": results["throughput_default"]["minutes_for_2000"]}))


if __name__ == "__main__":
    main()
