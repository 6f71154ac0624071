"""Palette benchmark: decode time of a 10k-point pattern, and the shipped build's recorded figures.

Targets (issue 3): decoding a 10,000-point pattern <= 1 s; the full build
(1,000 x 1,024) <= 60 min on 2 cores — the build times itself and records the
stage timings in ``synthesis/assets/palette.json``; this benchmark reports them
rather than rebuilding for an hour (``python -m data_gen.palette`` with an empty
``cache_dir`` reproduces the figure).
"""

from __future__ import annotations

import json

import numpy as np
import torch

from common import median_seconds, save_results  # bench/ is on sys.path when run as a script

from synthesis.generators import generate
from synthesis.palette import DEFAULT_PALETTE, Palette


def main() -> None:
    palette = Palette.load()
    record = json.loads(DEFAULT_PALETTE.with_suffix(".json").read_text())
    results = {"asset_mb": round(DEFAULT_PALETTE.stat().st_size / 2**20, 2), "build_timings_s": record["timings_s"],
               "build_metrics": record["metrics"], "decode_10k": {}}
    points = generate("blue", 10_000, seed=3)
    for threads in (1, 2):
        torch.set_num_threads(threads)
        median, times = median_seconds(lambda: palette.decode(points), repeats=5)
        results["decode_10k"][f"threads_{threads}"] = {"median_s": round(median, 3), "runs_s": [round(t, 3) for t in times]}
    results["decode_10k_target_s"] = 1.0
    results["build_total_min"] = round(record["timings_s"]["total"] / 60.0, 1)
    results["build_corpus_exemplars_computed"] = record.get("corpus_exemplars_computed")
    results["build_corpus_worker_seconds"] = record.get("corpus_worker_seconds")
    results["build_note"] = ("build_total_min is a full build only when build_corpus_exemplars_computed is 1000; "
                             "otherwise the corpus came from the cache")
    results["build_target_min"] = 60
    save_results("palette", results)


if __name__ == "__main__":
    main()
