"""Synthesis speed benchmark: wall time and peak memory from 10k to 1M points, start-up, and references.

Every run is a child process (its peak resident memory is its own; nothing
warm is shared): a constant map (L = 50, the ``blue`` preset) on the unit
square, the default schedule, ``--threads`` numba threads. Reported per case:
the synthesis wall time (``synthesize()``, imports excluded; the median of
3 runs up to 100k points, one run above) on 2 threads
and, up to 100k points, on 1 thread, its set-up share,
milliseconds per iteration, the peak resident memory and the final loss; the
CLI's start-up (``patternshop synthesize`` of 1,000 points with 1 iteration,
whole process); and the same-run wall time of scipy's ``qmc.PoissonDisk`` and
of the weighted Lloyd stippler (``data_gen.stipplers``, 60 iterations on a
grid of 4 pixels per point) at equal n, with the ratios. The load average is recorded before and after every case: the machine
is shared, so compare figures of one run only.

Targets: 10k <= 1 s after start-up, 100k <= 10 s, 1M <= 2 min and <= 1.5 GB,
start-up < 1 s, 100k at least 5x faster than PoissonDisk.

Run with ``make bench`` or ``python bench/bench_speed.py [--quick] [--threads T]``;
results go to ``out/bench/speed.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import save_results  # bench/ is on sys.path when run as a script

ROOT = Path(__file__).resolve().parent.parent
SIZES = (10_000, 100_000, 300_000, 1_000_000)
QUICK_SIZES = (10_000, 100_000)
REFERENCE_SIZES = (10_000, 100_000)
ONE_THREAD_UP_TO = 100_000
MAP_SIDE = 256
LLOYD_PIXELS_PER_POINT = 4  # the stippler's centroids live on its pixel grid: a few pixels per point


def _child(kind: str, n: int, threads: int) -> dict:
    """Run one case in this process and return its figures (called in a child)."""
    import numpy as np

    if kind == "synthesis":
        from synthesis.labmap import LabMap
        from synthesis.palette import load_palette
        from synthesis.synthesize import synthesize

        palette = load_palette()
        lab = np.zeros((MAP_SIDE, MAP_SIDE, 3), np.float32)
        lab[..., 0] = 50.0
        lab[..., 1:] = palette.preset_ab()["blue"]
        start = time.perf_counter()
        result = synthesize(LabMap(lab), n=n, palette=palette, seed=0, threads=threads)
        seconds = time.perf_counter() - start
        figures = {"seconds": seconds, "setup_seconds": result.setup_seconds, "final_loss": result.final_loss,
                   "ms_per_iteration": 1000 * (seconds - result.setup_seconds) / result.iterations}
    elif kind == "poisson_disk":
        from data_gen.stipplers import poisson_disk

        start = time.perf_counter()
        points = poisson_disk(n, seed=0)
        figures = {"seconds": time.perf_counter() - start, "points": len(points)}
    elif kind == "lloyd":
        from data_gen.stipplers import lloyd_stipple

        side = int(np.ceil(np.sqrt(LLOYD_PIXELS_PER_POINT * n)))
        start = time.perf_counter()
        points = lloyd_stipple(np.ones((side, side)), n, seed=0)
        figures = {"seconds": time.perf_counter() - start, "points": len(points)}
    else:
        raise ValueError(kind)
    figures["peak_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9
    return figures


def _run(kind: str, n: int, threads: int) -> dict:
    """The figures of the median-time run of ``repeats_for(n)`` child processes, with every run's time."""
    env = os.environ | {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": str(threads), "PYTHONPATH": str(ROOT)}
    runs = []
    for _ in range(repeats_for(n)):
        load_before = os.getloadavg()[0]
        done = subprocess.run([sys.executable, __file__, "--child", kind, "--n", str(n), "--threads", str(threads)],
                              cwd=ROOT, env=env, capture_output=True, text=True, check=True)
        figures = json.loads(done.stdout.strip().splitlines()[-1])
        runs.append(figures | {"load_before": round(load_before, 2), "load_after": round(os.getloadavg()[0], 2)})
    figures = sorted(runs, key=lambda run: run["seconds"])[len(runs) // 2] | {"runs_s": [round(run["seconds"], 3) for run in runs]}
    print(f"  {kind:13s} n={n:>9,} threads={threads}: {figures['seconds']:8.2f} s (median of {len(runs)}), peak "
          f"{figures['peak_gb']:.2f} GB (load {figures['load_before']:.1f} -> {figures['load_after']:.1f})", flush=True)
    return {key: round(value, 4) if isinstance(value, float) else value for key, value in figures.items()}


def repeats_for(n: int) -> int:
    """Runs per case: the median of 3 up to 100k points, one run above (minutes each)."""
    return 3 if n <= ONE_THREAD_UP_TO else 1


def _startup(threads: int) -> dict:
    """Whole-process wall time of the CLI on 1,000 points and 1 iteration (imports, palette, map, fields, start, writing)."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "p.txt"
        command = [str(Path(sys.executable).with_name("patternshop")), "synthesize", str(ROOT / "examples" / "logo.tif"),
                   str(out), "--points", "1000", "--iterations", "1", "--no-progress", "--threads", str(threads)]
        times = []
        for _ in range(3):
            start = time.perf_counter()
            subprocess.run(command, check=True, capture_output=True, env=os.environ | {"OMP_NUM_THREADS": "1"})
            times.append(time.perf_counter() - start)
    return {"median_s": round(sorted(times)[1], 3), "runs_s": [round(t, 3) for t in times]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help=f"only {', '.join(f'{n:,}' for n in QUICK_SIZES)} points")
    parser.add_argument("--threads", type=int, default=2, help="numba threads of the syntheses (default 2; up to 100k "
                        "points they also run on 1 thread)")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--n", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_child(args.child, args.n, args.threads)))
        return
    results: dict = {"threads": args.threads, "cpus": os.cpu_count(), "map": f"constant L=50 blue preset, {MAP_SIDE}^2 px, unit square",
                     "startup": _startup(1), "synthesis": {}, "synthesis_1_thread": {}, "references": {}}
    print(f"  start-up (CLI, 1,000 points, 1 iteration): {results['startup']['median_s']} s", flush=True)
    for n in QUICK_SIZES if args.quick else SIZES:
        results["synthesis"][str(n)] = _run("synthesis", n, args.threads)
        if n <= ONE_THREAD_UP_TO and args.threads != 1:
            results["synthesis_1_thread"][str(n)] = _run("synthesis", n, 1)
    for n in REFERENCE_SIZES:
        for kind in ("poisson_disk", "lloyd"):
            results["references"][f"{kind}_{n}"] = _run(kind, n, 1)
    ratios = {}
    for n in REFERENCE_SIZES:
        ours = results["synthesis"][str(n)]["seconds"]
        ratios[str(n)] = {f"{kind}_over_synthesis": round(results["references"][f"{kind}_{n}"]["seconds"] / ours, 2)
                          for kind in ("poisson_disk", "lloyd")}
    results["ratios"] = ratios
    synthesis = results["synthesis"]
    results["targets"] = {
        "startup_below_1s": results["startup"]["median_s"] < 1.0,
        "10k_at_most_1s_after_startup": synthesis["10000"]["seconds"] <= 1.0,
        "100k_at_most_10s": synthesis["100000"]["seconds"] <= 10.0,
        "100k_5x_faster_than_poisson_disk": ratios["100000"]["poisson_disk_over_synthesis"] >= 5.0,
    }
    if "1000000" in synthesis:
        results["targets"]["1M_at_most_120s"] = synthesis["1000000"]["seconds"] <= 120.0
        results["targets"]["1M_at_most_1.5GB"] = synthesis["1000000"]["peak_gb"] <= 1.5
    save_results("speed", results)


if __name__ == "__main__":
    main()
