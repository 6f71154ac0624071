"""``infer`` and ``convert`` cost on 20,000-point stipplings (issue 28: <= 1 s per map on one thread, >= 10 files/s
on two workers).

1. **infer, in this process**: :func:`export.runtime.infer_map` as ``infer`` runs it (model loaded, points read),
   median of ``--repeats`` (>= 5) per model and symmetry count, split into the network passes
   (:meth:`export.runtime.OnnxModel.predict_outputs`) and the rest; reading the point file and writing the TIFF
   are timed apart.
2. **infer, the command**: ``patternshop infer FILE OUT.tif --threads 1`` in a fresh process (Python start, imports,
   model load included), median of ``--repeats``.
3. **convert**: ``patternshop convert IN OUT --workers 2 --threads 1`` over ``--files`` point files in a fresh
   process (start-up included), files per second.

Inputs: scikit-image ``camera`` (a development picture, ``docs/evaluation.md``) stippled with 20,000 points by
density-proportional random sampling and by Floyd-Steinberg dithering (:mod:`data_gen.stipplers`), each file with
its true ``# points_per_ink`` header, as ``synthesize`` writes it. Models: the shipped one and each ``--model``
(a model with an ``l_scale`` output runs the uncertainty path, :mod:`export.uncertainty`).

Run with ``make bench`` (or ``python bench/bench_infer.py [--quick] [--model FILE ...]``); results go to
``out/bench/infer.json`` with the CPU count and the load average before and after (the machine is shared:
compare only figures of one run).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from common import median_seconds, save_results  # bench/ is on sys.path when run as a script

from data_gen.stipplers import METHODS
from export.evidence import pattern_scale
from export.infer_config import DEFAULT_INFER, SYMMETRY_CHOICES
from export.runtime import DEFAULT_MODEL, OnnxModel, V5_SYMMETRIES, infer_map
from patternshop_nn.ood import picture_density, points_per_ink_of
from synthesis.mapio import write_map
from synthesis.points import PointSet, read_points, write_points

ROOT = Path(__file__).resolve().parent.parent
POINTS = 20_000
TARGET_SECONDS = 1.0
TARGET_FILES_PER_SECOND = 10.0


def stipplings(folder: Path, files: int) -> list[Path]:
    """``files`` point files of ``camera``: random and Floyd-Steinberg stipplings, seeds 0, 1 ... (true scale in the header)."""
    density, domain = picture_density("camera")
    paths = []
    for k in range(files):
        method = ("random", "floyd_steinberg")[k % 2]
        xy = METHODS[method](density, POINTS, domain, np.random.default_rng(k))
        path = folder / f"camera_{method}_{k:03d}.txt"
        write_points(PointSet(xy, domain, points_per_ink=points_per_ink_of(len(xy), density)), path)
        paths.append(path)
    return paths


def in_process(model: OnnxModel, path: Path, symmetries: int, repeats: int, out: Path) -> dict:
    """Section 1 for one model, file and symmetry count."""
    points = read_points(path)
    scale = pattern_scale(points)
    network = []
    predict = model.predict_outputs

    def timed_predict(rasters: np.ndarray) -> np.ndarray:
        start = time.perf_counter()
        result = predict(rasters)
        network[-1] += time.perf_counter() - start
        return result

    def run() -> None:
        network.append(0.0)
        infer_map(points, model, scale=scale, symmetries=symmetries)

    model.predict_outputs = timed_predict  # an instance attribute shadows the method for this model only
    try:
        total, times = median_seconds(run, repeats)
    finally:
        del model.predict_outputs
    passes = network[1:]  # the warm-up run's left out, as median_seconds leaves it out
    inference = infer_map(points, model, scale=scale, symmetries=symmetries)
    read, _ = median_seconds(lambda: read_points(path), repeats)
    write, _ = median_seconds(lambda: write_map(inference.lab_map, out), repeats)
    return {"symmetries": symmetries, "infer_map_s": round(total, 3), "min_s": round(min(times), 3),
            "network_s": round(statistics.median(passes), 3), "rest_s": round(statistics.median(np.subtract(times, passes)), 3),
            "read_points_s": round(read, 4), "write_tiff_s": round(write, 4),
            "with_io_s": round(total + read + write, 3), "target_met": total + read + write <= TARGET_SECONDS}


def command_seconds(arguments: list[str], repeats: int) -> list[float]:
    """Wall seconds of ``patternshop ARGUMENTS`` in fresh processes, ``repeats`` times."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "patternshop", *arguments], check=True, capture_output=True, cwd=ROOT,
                       env={**os.environ, "OMP_NUM_THREADS": "1"})
        times.append(time.perf_counter() - start)
    return times


def model_results(path: Path, inputs: list[Path], convert_dir: Path, tmp: Path, repeats: int, quick: bool) -> dict:
    model = OnnxModel(path, threads=1)
    counts = (DEFAULT_INFER.symmetries, DEFAULT_INFER.convert_symmetries) if quick else SYMMETRY_CHOICES
    default = DEFAULT_INFER.symmetries if model.has_l_scale else V5_SYMMETRIES
    rows = {f"{source.stem} x{s}": in_process(model, source, s, repeats, tmp / "map.tif")
            for source in inputs for s in sorted({*counts, default})}
    command = command_seconds(["infer", str(inputs[0]), str(tmp / "cli.tif"), "--threads", "1", "--model", str(path)], repeats)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "patternshop", "convert", str(convert_dir), str(tmp / f"maps_{path.stem}"),
                    "--workers", "2", "--threads", "1", "--overwrite", "--no-progress", "--model", str(path)],
                   check=True, capture_output=True, cwd=ROOT)
    files = len(list(convert_dir.glob("*.txt")))
    seconds = time.perf_counter() - start
    return {"model": str(path), "has_l_scale": model.has_l_scale, "default_symmetries": default, "in_process": rows,
            "command_s": {"median": round(statistics.median(command), 3), "all": [round(t, 3) for t in command],
                          "symmetries": default, "target_met": statistics.median(command) <= TARGET_SECONDS},
            "convert": {"files": files, "seconds": round(seconds, 2), "files_per_second": round(files / seconds, 2),
                        "symmetries": DEFAULT_INFER.convert_symmetries if model.has_l_scale else 1,
                        "target_met": files / seconds >= TARGET_FILES_PER_SECOND}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", action="append", default=[], help="another ONNX model to time (repeatable)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per figure (default 5)")
    parser.add_argument("--files", type=int, default=40, help="point files for convert (default 40)")
    parser.add_argument("--quick", action="store_true", help="only the default symmetry counts, 20 files")
    args = parser.parse_args()
    if args.repeats < 5:
        parser.error("--repeats must be at least 5 (medians of fewer runs on a shared machine mislead)")
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as scratch:
        tmp = Path(scratch)
        convert_dir = tmp / "points"
        convert_dir.mkdir()
        inputs = stipplings(convert_dir, 20 if args.quick else args.files)[:2]
        models = [DEFAULT_MODEL, *map(Path, args.model)]
        results = {"cpus": os.cpu_count(), "load_average_before": [round(x, 2) for x in load_before],
                   "points": POINTS, "target_seconds_per_map": TARGET_SECONDS,
                   "target_files_per_second": TARGET_FILES_PER_SECOND,
                   "models": [model_results(m, inputs, convert_dir, tmp, args.repeats, args.quick) for m in models],
                   "load_average_after": [round(x, 2) for x in os.getloadavg()]}
    save_results("infer", results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
