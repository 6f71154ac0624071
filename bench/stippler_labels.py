"""Measure the correlation label of every stippler of data_gen/stipplers.py: decode stationary samples with the palette.

``python bench/stippler_labels.py [--n 2048] [--seeds 3] [--methods NAME ...] [--out bench/stippler_labels.json]``

Each method stipples a constant density (0.2, 0.4 and 0.6; ``--n`` points on the unit square) at ``--seeds``
seeds; :meth:`synthesis.palette.Palette.locate` (what ``patternshop analyze`` reports as its colour) decodes
each sample; the table gives the mean a, b, their spread (RMS distance to the mean, ab units), the nearest
preset and its distance. The shipped palette decodes; the frozen test-set methods are measured too (their
labels are never used for training). ``--methods`` measures only those (a lattice's rotation and offset come
from the seed).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data_gen.stipplers import FROZEN_METHODS, METHODS  # noqa: E402
from synthesis.palette import load_palette  # noqa: E402

DENSITIES = (0.2, 0.4, 0.6)


def measure(n: int, seeds: int, methods: list[str] | None = None) -> list[dict]:
    palette = load_palette()
    presets = palette.preset_ab()
    rows = []
    for name, method in {**METHODS, **FROZEN_METHODS}.items():
        if methods and name not in methods:
            continue
        start = time.perf_counter()
        ab = []
        for density in DENSITIES:
            for seed in range(seeds):
                xy = method(np.full((64, 64), density), n, (1.0, 1.0), np.random.default_rng(seed))
                decoded = palette.locate(xy)
                ab.append((decoded.a, decoded.b))
        ab = np.array(ab)
        mean = ab.mean(axis=0)
        nearest = palette.nearest_preset(*mean)
        rows.append({"method": name, "frozen": name in FROZEN_METHODS, "a": round(float(mean[0]), 1), "b": round(float(mean[1]), 1),
                     "spread": round(float(np.sqrt(np.mean(np.sum((ab - mean) ** 2, axis=1)))), 1),
                     "nearest_preset": nearest,
                     "preset_distance": round(float(np.hypot(*(np.array(presets[nearest]) - mean))), 1),
                     "samples": [[round(float(a), 1), round(float(b), 1)] for a, b in ab],
                     "seconds": round(time.perf_counter() - start, 1)})
        print(json.dumps({k: v for k, v in rows[-1].items() if k != "samples"}), flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=2048)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--methods", nargs="*", help="only these methods (default: all)")
    parser.add_argument("--out", default="bench/stippler_labels.json")
    args = parser.parse_args()
    rows = measure(args.n, args.seeds, args.methods)
    Path(args.out).write_text(json.dumps({"n": args.n, "densities": DENSITIES, "seeds": args.seeds, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
