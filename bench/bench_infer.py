"""``infer`` and ``convert`` cost on 20,000-point stipplings (issue 28: <= 1 s per map on one thread, >= 10 files/s
on two workers).

1. **infer, in this process**: :func:`export.runtime.infer_map` as ``infer`` runs it (model loaded, points read),
   median of ``--repeats`` (>= 5) per model and symmetry count, split into the network passes
   (:meth:`export.runtime.OnnxModel.predict_outputs`) and the rest; reading the point file and writing the TIFF
   are timed apart.
2. **infer, the command**: ``patternshop infer FILE OUT.tif --threads 1`` in a fresh process (Python start, imports,
   model load included), median of ``--repeats``.
3. **convert**: ``patternshop convert IN OUT --workers 2 --threads 1`` over ``--files`` point files in a fresh
   process (start-up included), files per second: ``--convert-repeats`` runs per model, the models interleaved
   (the shipped model, the next model, the shipped model ...), each run with the 1-minute load average after it. Besides, the CPU seconds one
   worker spends per file (:func:`export.convert.convert_points` in this process over the same files, warmed up),
   split into reading the point file, :func:`export.runtime.infer_map` (of which the network passes, the
   degeneracy check, the smoothing of a model with ``l_scale``, the water-filling, and the rest) and writing the
   TIFF: on two idle cores two workers convert about ``2 / cpu_per_file_s`` files per second once started
   (``two_started_workers_files_per_second``, a figure from CPU time, not a run).

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
from export.runtime import DEFAULT_MODEL, OnnxModel, infer_map
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
    rows = {f"{source.stem} x{s}": in_process(model, source, s, repeats, tmp / "map.tif")
            for source in inputs for s in sorted({*counts, DEFAULT_INFER.symmetries})}
    command = command_seconds(["infer", str(inputs[0]), str(tmp / "cli.tif"), "--threads", "1", "--model", str(path)], repeats)
    return {"model": str(path), "has_l_scale": model.has_l_scale, "default_symmetries": DEFAULT_INFER.symmetries, "in_process": rows,
            "command_s": {"median": round(statistics.median(command), 3), "all": [round(t, 3) for t in command],
                          "symmetries": DEFAULT_INFER.symmetries, "target_met": statistics.median(command) <= TARGET_SECONDS},
            "convert": {"symmetries": DEFAULT_INFER.convert_symmetries, **convert_cpu(model, convert_dir, tmp / "cpu")}}


def convert_cpu(model: OnnxModel, convert_dir: Path, out: Path) -> dict:
    """CPU seconds per file of one worker's work (section 3): convert_points in this process (one thread), after a
    warm-up file, in total and by stage (the stages' functions wrapped with CPU clocks for the run)."""
    import export.convert
    import export.runtime
    import synthesis.analysis
    import synthesis.mapio

    sources = sorted(convert_dir.glob("*.txt"))
    export.convert.convert_points(sources[:1], out, model, workers=1, overwrite=True)
    stages = {"read_points": (export.convert, "read_points"), "infer_map": (export.runtime, "infer_map"),  # looked up per call
              "network": (model, "predict_outputs"), "degeneracy_check": (synthesis.analysis, "check_not_degenerate"),
              "smoothing": (export.runtime, "smooth_by_uncertainty"), "water_filling": (export.runtime, "calibrate_density"),
              "write_tiff": (synthesis.mapio, "write_tiff")}
    spent = dict.fromkeys(stages, 0.0)

    def clocked(name: str, function):  # noqa: ANN001, ANN202 - any of the stages
        def run(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            start = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                spent[name] += time.process_time() - start
        return run

    originals = {name: getattr(owner, attribute) for name, (owner, attribute) in stages.items()}
    for name, (owner, attribute) in stages.items():
        setattr(owner, attribute, clocked(name, originals[name]))
    try:
        start = time.process_time()
        export.convert.convert_points(sources, out, model, workers=1, overwrite=True)
        total = time.process_time() - start
    finally:
        for name, (owner, attribute) in stages.items():
            if owner is model:
                del model.predict_outputs  # the instance attribute set above: the method shows again
            else:
                setattr(owner, attribute, originals[name])
    per_file = {f"{name}_s": round(seconds / len(sources), 4) for name, seconds in spent.items()}
    parts = ("network", "degeneracy_check", "smoothing", "water_filling")  # inside infer_map
    per_file["infer_map_rest_s"] = round(per_file["infer_map_s"] - sum(per_file[f"{name}_s"] for name in parts), 4)
    return {"cpu_per_file_s": round(total / len(sources), 4), "cpu_per_file_by_stage": per_file,
            "two_started_workers_files_per_second": round(2 * len(sources) / total, 1)}


def convert_runs(models: list[Path], convert_dir: Path, tmp: Path, repeats: int) -> dict[Path, dict]:
    """Section 3's command: ``repeats`` runs per model, the models interleaved, each with the load after it."""
    files = len(list(convert_dir.glob("*.txt")))
    runs: dict[Path, list[tuple[float, float]]] = {path: [] for path in models}
    for _ in range(repeats):
        for path in models:
            start = time.perf_counter()
            subprocess.run([sys.executable, "-m", "patternshop", "convert", str(convert_dir), str(tmp / f"maps_{path.stem}"),
                            "--workers", "2", "--threads", "1", "--overwrite", "--no-progress", "--model", str(path)],
                           check=True, capture_output=True, cwd=ROOT, env={**os.environ, "OMP_NUM_THREADS": "1"})
            runs[path].append((time.perf_counter() - start, os.getloadavg()[0]))
    results = {}
    for path, timed in runs.items():
        rates = [files / seconds for seconds, _ in timed]
        results[path] = {"files": files, "workers": 2, "files_per_second": round(statistics.median(rates), 2),
                         "all_files_per_second": [round(r, 2) for r in rates], "load_after": [round(load, 2) for _, load in timed],
                         "target_met": statistics.median(rates) >= TARGET_FILES_PER_SECOND}
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", action="append", default=[], help="another ONNX model to time (repeatable)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per figure (default 5)")
    parser.add_argument("--files", type=int, default=40, help="point files for convert (default 40)")
    parser.add_argument("--convert-repeats", type=int, default=3, help="convert runs per model, interleaved (default 3)")
    parser.add_argument("--quick", action="store_true", help="only the default symmetry counts, 20 files")
    args = parser.parse_args()
    if args.repeats < 5:
        parser.error("--repeats must be at least 5 (medians of fewer runs on a shared machine mislead)")
    if args.convert_repeats < 1:
        parser.error("--convert-repeats must be at least 1")
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
                   "models": [model_results(m, inputs, convert_dir, tmp, args.repeats, args.quick) for m in models]}
        for row, (path, runs) in zip(results["models"], convert_runs(models, convert_dir, tmp, args.convert_repeats).items()):
            row["convert"].update(runs)
        results["load_average_after"] = [round(x, 2) for x in os.getloadavg()]
    save_results("infer", results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
