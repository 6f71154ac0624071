"""The network's own a, b (one pass, no zoom, no calibration) of uniform patterns: light Poisson and lattices.

Two figures of the trial trainings in ``docs/network.md`` (v6, v6c, v7), measured the same way for every model:

* **light patterns**: each of ``random`` (Poisson), ``poisson_disk``, ``jitter``, ``clusters`` and ``lloyd``
  (:data:`data_gen.stipplers.METHODS`) stipples a constant density 0.05, 0.1, 0.2 and 0.5 with ``8000 x density``
  points on the unit square (the training scale: 8,000 points per ink, a 256 px raster), seeds 200-202; the mean
  a, b over the raster's interior (32 px in from each side) and its distance to the method's training label
  (:data:`data_gen.stipplers.LABELS`; Poisson's is white, so this is its distance from white);
* **lattices**: square and hexagonal lattices, plain (jitter 0.05 spacings) and jittered (0.2), and Poisson and
  Poisson-disk for comparison, 4,000 points at density 0.5, six realisations (seeds 100-105, each its own random
  rotation and offset; not the label seeds 0-7): the mean a, b, its distance to the label, the RMS spread and the
  largest distance between two rotations (the "colour spread over rotations" of the tables).

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_raw_colours.py MODEL.onnx [MODEL.onnx ...]

Results go to ``out/bench/raw_colours.json``, one entry per model.
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys

import numpy as np

from common import save_results  # bench/ is on sys.path when run as a script

from data_gen.stipplers import LABELS, METHODS
from export.runtime import OnnxModel
from synthesis.palette import load_palette
from synthesis.raster import point_raster

RASTER = 256
POINTS_PER_INK = 8000
MARGIN_PX = 32
LIGHT_METHODS = ("random", "poisson_disk", "jitter", "clusters", "lloyd")
LIGHT_DENSITIES = (0.05, 0.1, 0.2, 0.5)
LIGHT_SEEDS = (200, 201, 202)
LATTICE_METHODS = ("lattice_square", "lattice_hex", "lattice_square_jitter", "lattice_hex_jitter", "random", "poisson_disk")
LATTICE_POINTS, LATTICE_DENSITY = 4000, 0.5
LATTICE_SEEDS = tuple(range(100, 106))


def mean_ab(model: OnnxModel, xy: np.ndarray) -> np.ndarray:
    """(2,) the network's mean a, b over the raster's interior for points ``xy`` (n, 2) on the unit square."""
    output = model.predict(point_raster(xy, RASTER)[None, None].astype(np.float32))[0]
    inner = output[1:, MARGIN_PX:-MARGIN_PX, MARGIN_PX:-MARGIN_PX].reshape(2, -1).mean(axis=1)
    return 255.0 * inner - 128.0


def label_ab(method: str, presets: dict) -> np.ndarray:
    label = LABELS[method]
    return np.array(presets[label] if isinstance(label, str) else label, np.float64)


def light(model: OnnxModel, presets: dict) -> dict:
    rows = {}
    for method, density in itertools.product(LIGHT_METHODS, LIGHT_DENSITIES):
        values = [mean_ab(model, METHODS[method](np.full((64, 64), density), int(POINTS_PER_INK * density), (1.0, 1.0),
                                                 np.random.default_rng(seed))) for seed in LIGHT_SEEDS]
        mean = np.mean(values, axis=0)
        rows[f"{method}@{density}"] = {"a": round(float(mean[0]), 1), "b": round(float(mean[1]), 1),
                                       "distance_to_label": round(float(np.hypot(*(mean - label_ab(method, presets)))), 1)}
    return rows


def lattices(model: OnnxModel, presets: dict) -> dict:
    rows = {}
    for method in LATTICE_METHODS:
        values = np.array([mean_ab(model, METHODS[method](np.full((64, 64), LATTICE_DENSITY), LATTICE_POINTS, (1.0, 1.0),
                                                          np.random.default_rng(seed))) for seed in LATTICE_SEEDS])
        mean = values.mean(axis=0)
        rows[method] = {"a": round(float(mean[0]), 1), "b": round(float(mean[1]), 1),
                        "distance_to_label": round(float(np.hypot(*(mean - label_ab(method, presets)))), 1),
                        "spread": round(float(np.sqrt(((values - mean) ** 2).sum(axis=1).mean())), 1),
                        "max_dist_between_rotations": round(float(max(np.hypot(*(v - w)) for v in values for w in values)), 1)}
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("models", nargs="+", help="ONNX models")
    args = parser.parse_args()
    presets = load_palette().preset_ab()
    results = {"load_average": os.getloadavg(), "models": {}}
    for path in args.models:
        model = OnnxModel(path, threads=1)
        results["models"][path] = {"light": light(model, presets), "lattices": lattices(model, presets)}
    save_results("raw_colours", results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
