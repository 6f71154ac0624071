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
is shared, so compare figures of one run only. The project's bytecode is written before any case, as an
installation has it (:func:`_compile_bytecode`).

Start-up (``startup_fresh_process``, issue 27): in one run, interleaved, :data:`STARTUP_RUNS`
fresh processes each of ``python -c "import patternshop"`` (whole process), of the CLI
(``patternshop synthesize examples/logo.tif ... --points 10000 --iterations 1``, run in a child
through ``patternshop.cli.main``) and of the API (``patternshop.synthesize("examples/logo.tif",
points=10000, iterations=1)``): seconds from the process's start to the first synthesis
iteration (the progress callback's ``done == 0``: imports, map, palette, fields and the
density-matched start done), to the end of that iteration, and of the whole process, and the
process's own CPU seconds at those points (``*_cpu_s``: steadier than wall time on a loaded machine); medians,
every run, the load average before and after, and which of torch, matplotlib and sklearn the
synthesis path imported. ``--startup-only`` runs this section alone.

Warm start (``warm_start``, one thread, one run): :data:`WARM_POINTS` points, a full run, a disc re-toned and its
points re-drawn (``redrawn_start``), then a full run and a warm start on the edited map: their seconds and the
disc's statistics from ``bench/fidelity_stats.py`` (see :func:`_warm_start_case`).

10k split (``synthesis_10k_split``, one thread, medians of 3 children; issue 27 frames 10k as "<= 1 s plus <= 0.5 s
start-up"): (a) the whole first ``synthesize()`` call in a fresh process (the ``synthesis`` row: it loads numba, the
kernels and the palette's tables inside the call), (b) the synthesis itself: a second call on the bench map in a process
whose first call ran on another map (:data:`WARM_UP_SIDE`-px, another lightness and preset, other n and seed: nothing
of the bench map's is computed there, and synthesis keeps no result between calls), and the start-up inside the first
call, (a) - (b); wall and CPU seconds each (``cpu_seconds``: steadier on a loaded machine).

Targets (issue 27; one thread, whole ``synthesize()`` call): 10k <= 1 s after start-up ((b) above, and (a) - (b) <=
0.5 s), 100k <= 10 s and at most
0.2 x PoissonDisk's time in the same run (the ratios use the 1-thread syntheses); 1M <= 2 min and <= 1.5 GB;
start-up < 1 s (and <= 0.5 s to the first iteration).

Run with ``make bench`` or ``python bench/bench_speed.py [--quick] [--threads T] [--startup-only]``;
results go to ``out/bench/speed.json``.
"""

from __future__ import annotations

import argparse
import compileall
import json
import os
import resource
import statistics
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
WARM_POINTS = 20_000  # the warm-start row: a full run, then a local edit (a disc re-toned) and a warm start
WARM_DISC = (0.5, 0.5, 0.25)  # the edited disc: centre x, y and radius, map units
WARM_L = 30.0  # its new lightness (the map's is 50)
STARTUP_RUNS = 5  # fresh processes per start-up case (medians)
WARM_UP_SIDE, WARM_UP_L, WARM_UP_PRESET, WARM_UP_POINTS = 64, 40.0, "step", 1_000  # the warm-up call's map, before
# the timed second call of ``synthesis_after_warm_up``: another size, lightness and colour (nothing of the bench map's)
STARTUP_POINTS = 10_000
STARTUP_MAP = ROOT / "examples" / "logo.tif"
PACKAGES = ("synthesis", "data_gen", "export", "patternshop_nn", "patternshop")  # bytecode written before timing
HEAVY_MODULES = ("torch", "matplotlib", "sklearn")  # the synthesis path needs none of them
SPAWNED_VARIABLE = "PATTERNSHOP_BENCH_SPAWNED"  # the parent's time.time() just before it started the child


def _child(kind: str, n: int, threads: int) -> dict:
    """Run one case in this process and return its figures (called in a child)."""
    import numpy as np

    if kind in ("synthesis", "synthesis_after_warm_up"):
        began, began_cpu = time.perf_counter(), time.process_time()
        from synthesis.labmap import LabMap
        from synthesis.palette import load_palette
        from synthesis.synthesize import synthesize

        palette = load_palette()
        figures = {"imports_s": time.perf_counter() - began}
        if kind == "synthesis_after_warm_up":  # numba, its kernels and the palette's tables loaded by another map's run
            warm_up = np.zeros((WARM_UP_SIDE, WARM_UP_SIDE, 3), np.float32)
            warm_up[..., 0] = WARM_UP_L
            warm_up[..., 1:] = palette.preset_ab()[WARM_UP_PRESET]
            synthesize(LabMap(warm_up), n=WARM_UP_POINTS, palette=palette, seed=1, threads=threads)
            figures["warm_up_call_s"] = time.perf_counter() - began - figures["imports_s"]
            figures["warm_up_cpu_s"] = time.process_time() - began_cpu  # imports and the warm-up call
        lab = np.zeros((MAP_SIDE, MAP_SIDE, 3), np.float32)
        lab[..., 0] = 50.0
        lab[..., 1:] = palette.preset_ab()["blue"]
        start, start_cpu = time.perf_counter(), time.process_time()
        result = synthesize(LabMap(lab), n=n, palette=palette, seed=0, threads=threads)
        seconds = time.perf_counter() - start
        figures |= {"seconds": seconds, "cpu_seconds": time.process_time() - start_cpu,
                    "setup_seconds": result.setup_seconds, "final_loss": result.final_loss,
                    "ms_per_iteration": 1000 * (seconds - result.setup_seconds) / result.iterations}
    elif kind == "warm_start":
        figures = _warm_start_case(n, threads)
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


def _warm_start_case(n: int, threads: int) -> dict:
    """The warm-start row (called in a child): a full run of ``n`` points on the bench map, then the disc
    :data:`WARM_DISC` re-toned to :data:`WARM_L` and its points re-drawn (``synthesis.synthesize.redrawn_start``).
    Seconds of a full run on the edited map and of the warm start from the re-drawn points, the disc's statistics
    after each (``bench/fidelity_stats.py``: nearest neighbours beyond a spacing of the disc's rim, in local r_max;
    the largest empty circle inside it; its count over the expected), and a warm start on the unedited map from the
    full run (how far points move, the pattern's NN statistics before and after)."""
    import numpy as np

    import fidelity_stats as fs
    from synthesis.labmap import LabMap
    from synthesis.palette import load_palette
    from synthesis.synthesize import redrawn_start, synthesize

    palette = load_palette()
    lab = np.zeros((MAP_SIDE, MAP_SIDE, 3), np.float32)
    lab[..., 0] = 50.0
    lab[..., 1:] = palette.preset_ab()["blue"]
    first = synthesize(LabMap(lab), n=n, palette=palette, seed=0, threads=threads)
    x, y, radius = WARM_DISC
    rows, columns = (np.mgrid[:MAP_SIDE, :MAP_SIDE] + 0.5) / MAP_SIDE
    region = np.hypot(columns - x, rows - y) < radius
    edited = lab.copy()
    edited[region, 0] = WARM_L
    edited_map = LabMap(edited)
    start = redrawn_start(edited_map, first.points.xy, region, seed=1, palette=palette)
    intensity = fs.Intensity(edited_map.density().astype(np.float64), edited_map.domain, len(start))
    inside_ink = edited_map.density().astype(np.float64) * region
    disc = fs.Intensity(inside_ink, edited_map.domain, len(start) * inside_ink.mean() / intensity.density.mean())

    def disc_statistics(xy: np.ndarray) -> dict:
        local = intensity.local_r_max(xy)
        nn = fs.nearest_neighbours(xy) / local
        rim = np.hypot(xy[:, 0] - x, xy[:, 1] - y)
        interior = rim < radius - local
        return {"disc_min_nn": float(nn[interior].min()), "disc_nn_cv": float(nn[interior].std() / nn[interior].mean()),
                "disc_stacked": float(np.mean(nn[rim < radius] < fs.STACKED)),
                "disc_largest_empty_circle": fs.empty_circles(xy, disc)["largest"],
                "disc_count_over_expected": float(np.sum(rim < radius) / disc.n)}

    figures: dict = {"points": len(start), "start": disc_statistics(start)}
    for name, keywords in (("full", {"n": len(start)}), ("warm", {"start_points": start})):
        began = time.perf_counter()
        result = synthesize(edited_map, palette=palette, seed=2, threads=threads, **keywords)
        figures[name] = {"seconds": time.perf_counter() - began, "iterations": result.iterations} | disc_statistics(result.points.xy)
    figures["warm_over_full"] = figures["warm"]["seconds"] / figures["full"]["seconds"]
    again = synthesize(LabMap(lab), palette=palette, seed=3, threads=threads, start_points=first.points.xy)
    constant = fs.Intensity.constant(n)
    moved = np.hypot(*(again.points.xy - first.points.xy).T) / constant.local_r_max(first.points.xy)
    before, after = fs.nn_stats(first.points.xy, constant), fs.nn_stats(again.points.xy, constant)
    figures["unedited"] = {"seconds": again.seconds, "moved_mean": float(moved.mean()), "moved_max": float(moved.max()),
                           "min_nn": [before["min_nn"], after["min_nn"]], "nn_cv": [before["nn_cv"], after["nn_cv"]]}
    figures["seconds"] = figures["warm"]["seconds"]
    return figures


def _startup_child(kind: str, n: int) -> dict:
    """One fresh-process start-up case (called in a child): seconds since the parent started it.

    ``kind``: ``"cli"`` (``patternshop.cli.main``, as the ``patternshop`` command runs it) or ``"api"``
    (``patternshop.synthesize``); both on :data:`STARTUP_MAP` with ``n`` points and one iteration.
    """
    spawned = float(os.environ[SPAWNED_VARIABLE])
    import patternshop
    from patternshop import api

    marks = {"import_patternshop_s": time.time() - spawned, "import_patternshop_cpu_s": time.process_time()}

    def timed(*args, progress=None, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202 - api.synthesize's own
        def callback(done, total, xy):  # noqa: ANN001
            if done <= 1:
                name = ("to_first_iteration", "through_first_iteration")[done]
                marks.setdefault(f"{name}_s", time.time() - spawned)
                marks.setdefault(f"{name}_cpu_s", time.process_time())  # this process's CPU seconds: steadier under load
            if progress is not None:
                progress(done, total, xy)
        return synthesize(*args, progress=callback, **kwargs)

    synthesize, api.synthesize = api.synthesize, timed
    if kind == "cli":
        from patternshop.cli import main

        with tempfile.TemporaryDirectory() as folder:
            status = main(["synthesize", str(STARTUP_MAP), str(Path(folder) / "p.txt"), "--points", str(n),
                           "--iterations", "1", "--no-progress", "--threads", "1"])
        if status:
            raise RuntimeError(f"patternshop synthesize exited {status}")
    elif kind == "api":
        patternshop.synthesize(STARTUP_MAP, points=n, iterations=1, seed=0, threads=1)
    else:
        raise ValueError(kind)
    return marks | {"heavy_modules": sorted(name for name in HEAVY_MODULES if name in sys.modules)}


def _fresh_process(arguments: list[str]) -> tuple[float, dict]:
    """Whole-process wall time of ``python ARGUMENTS`` and the JSON on its last output line (if any)."""
    env = os.environ | {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1", "PYTHONPATH": str(ROOT),
                        SPAWNED_VARIABLE: repr(time.time())}
    start = time.perf_counter()
    done = subprocess.run([sys.executable, *arguments], cwd=ROOT, env=env, capture_output=True, text=True, check=True)
    seconds = time.perf_counter() - start
    lines = done.stdout.strip().splitlines()
    return seconds, (json.loads(lines[-1]) if lines and lines[-1].startswith("{") else {})


def _compile_bytecode() -> None:
    """Write the project's bytecode (``__pycache__``, ignored by git), as ``pip install`` does: with
    ``PYTHONDONTWRITEBYTECODE`` set (some sandboxes and CI images set it), every fresh process would compile the
    synthesis modules it imports from source again (about 30 ms of the start-up a user never pays)."""
    for package in PACKAGES:
        compileall.compile_dir(ROOT / package, quiet=2)


def _startup_fresh_process(runs: int = STARTUP_RUNS, n: int = STARTUP_POINTS) -> dict:
    """Start-up figures of fresh processes (see the module docstring): ``import patternshop``, the CLI and the API,
    interleaved run by run so that the machine's drift touches all three alike; medians and every run."""
    cases = {"import_patternshop": ["-c", "import patternshop"],
             "cli": [__file__, "--child", "startup_cli", "--n", str(n)],
             "api": [__file__, "--child", "startup_api", "--n", str(n)]}
    _fresh_process(cases["api"])  # warm-up: the file cache, and numba's on-disk cache after an edit
    load_before = os.getloadavg()
    runs_by_case: dict[str, list[dict]] = {name: [] for name in cases}
    for _ in range(runs):
        for name, arguments in cases.items():
            seconds, marks = _fresh_process(arguments)
            runs_by_case[name].append(marks | {"whole_process_s": seconds})
    load_after = os.getloadavg()
    results: dict = {"points": n, "map": str(STARTUP_MAP.relative_to(ROOT)), "iterations": 1, "threads": 1, "runs": runs,
                     "load_average_before": [round(x, 2) for x in load_before],
                     "load_average_after": [round(x, 2) for x in load_after]}
    for name, case_runs in runs_by_case.items():
        figures: dict = {}
        for key in ("import_patternshop_s", "to_first_iteration_s", "through_first_iteration_s", "whole_process_s",
                    "import_patternshop_cpu_s", "to_first_iteration_cpu_s", "through_first_iteration_cpu_s"):
            values = [run[key] for run in case_runs if key in run]
            if values:
                figures[key] = {"median": round(statistics.median(values), 3), "runs": [round(v, 3) for v in values]}
        if case_runs and "heavy_modules" in case_runs[0]:
            figures["heavy_modules_imported"] = case_runs[0]["heavy_modules"]
        results[name] = figures
    for name in ("cli", "api"):
        print(f"  start-up {name:3s} ({n:,} points, logo.tif): first iteration at "
              f"{results[name]['to_first_iteration_s']['median']:.2f} s, whole process "
              f"{results[name]['whole_process_s']['median']:.2f} s (medians of {runs})", flush=True)
    print(f"  python -c 'import patternshop': {results['import_patternshop']['whole_process_s']['median']:.2f} s; "
          f"load average {load_before[0]:.1f} -> {load_after[0]:.1f}", flush=True)
    return results


def _run(kind: str, n: int, threads: int, repeats: int | None = None) -> dict:
    """The figures of the median-time run of ``repeats`` (default ``repeats_for(n)``) child processes, with every run's time."""
    env = os.environ | {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": str(threads), "PYTHONPATH": str(ROOT)}
    runs = []
    for _ in range(repeats or repeats_for(n)):
        load_before = os.getloadavg()[0]
        done = subprocess.run([sys.executable, __file__, "--child", kind, "--n", str(n), "--threads", str(threads)],
                              cwd=ROOT, env=env, capture_output=True, text=True, check=True)
        figures = json.loads(done.stdout.strip().splitlines()[-1])
        runs.append(figures | {"load_before": round(load_before, 2), "load_after": round(os.getloadavg()[0], 2)})
    figures = sorted(runs, key=lambda run: run["seconds"])[len(runs) // 2] | {"runs_s": [round(run["seconds"], 3) for run in runs]}
    cpu = f" ({figures['cpu_seconds']:.2f} s CPU)" if "cpu_seconds" in figures else ""
    print(f"  {kind:13s} n={n:>9,} threads={threads}: {figures['seconds']:8.2f} s{cpu} (median of {len(runs)}), peak "
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
    parser.add_argument("--startup-only", action="store_true", help="only the fresh-process start-up section "
                        "(results go to out/bench/speed_startup.json)")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--n", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        if args.child.startswith("startup_"):
            print(json.dumps(_startup_child(args.child.removeprefix("startup_"), args.n)))
        else:
            print(json.dumps(_child(args.child, args.n, args.threads)))
        return
    _compile_bytecode()
    if args.startup_only:
        save_results("speed_startup", {"cpus": os.cpu_count(), "startup_fresh_process": _startup_fresh_process()})
        return
    results: dict = {"threads": args.threads, "cpus": os.cpu_count(), "map": f"constant L=50 blue preset, {MAP_SIDE}^2 px, unit square",
                     "startup": _startup(1), "synthesis": {}, "synthesis_1_thread": {}, "references": {}}
    print(f"  start-up (CLI, 1,000 points, 1 iteration): {results['startup']['median_s']} s", flush=True)
    results["startup_fresh_process"] = _startup_fresh_process()
    for n in QUICK_SIZES if args.quick else SIZES:
        results["synthesis"][str(n)] = _run("synthesis", n, args.threads)
        if n <= ONE_THREAD_UP_TO and args.threads != 1:
            results["synthesis_1_thread"][str(n)] = _run("synthesis", n, 1)
    one_thread = results["synthesis"] if args.threads == 1 else results["synthesis_1_thread"]
    split = results["synthesis_10k_split"] = _run("synthesis_after_warm_up", 10_000, 1)
    split["start_up_in_first_call_s"] = round(one_thread["10000"]["seconds"] - split["seconds"], 4)
    split["start_up_in_first_call_cpu_s"] = round(one_thread["10000"]["cpu_seconds"] - split["cpu_seconds"], 4)
    print(f"  10k, 1 thread: (a) whole first call in a fresh process {one_thread['10000']['seconds']:.2f} s "
          f"({one_thread['10000']['cpu_seconds']:.2f} s CPU) = (b) the synthesis, a second call after a warm-up on "
          f"another map, {split['seconds']:.2f} s ({split['cpu_seconds']:.2f} s CPU) + start-up inside the first call "
          f"{split['start_up_in_first_call_s']:.2f} s ({split['start_up_in_first_call_cpu_s']:.2f} s CPU); imports "
          f"before the call {split['imports_s']:.2f} s", flush=True)
    for n in REFERENCE_SIZES:
        for kind in ("poisson_disk", "lloyd"):
            results["references"][f"{kind}_{n}"] = _run(kind, n, 1)
    warm = results["warm_start"] = _run("warm_start", WARM_POINTS, 1, repeats=1)
    print(f"  warm start ({warm['points']:,} points, 1 thread, a disc re-toned): full run {warm['full']['seconds']:.2f} s, "
          f"warm {warm['warm']['seconds']:.2f} s; the disc's min NN {warm['full']['disc_min_nn']:.3f} / "
          f"{warm['warm']['disc_min_nn']:.3f}, NN CV {warm['full']['disc_nn_cv']:.4f} / {warm['warm']['disc_nn_cv']:.4f}",
          flush=True)
    ratios = {}  # the targets are on one thread: the references against the 1-thread syntheses of this run
    for n in REFERENCE_SIZES:
        ours = one_thread[str(n)]["seconds"]
        ratios[str(n)] = {f"{kind}_over_synthesis_1_thread": round(results["references"][f"{kind}_{n}"]["seconds"] / ours, 2)
                          for kind in ("poisson_disk", "lloyd")}
        print(f"  n={n:,}: synthesis on 1 thread {ours:.2f} s = {1 / ratios[str(n)]['poisson_disk_over_synthesis_1_thread']:.2f}"
              " x PoissonDisk's time", flush=True)
    results["ratios"] = ratios
    synthesis = results["synthesis"]
    results["targets"] = {
        "startup_below_1s": results["startup"]["median_s"] < 1.0,
        "startup_to_first_iteration_at_most_0.5s": results["startup_fresh_process"]["cli"]["to_first_iteration_s"]["median"] <= 0.5,
        "10k_synthesis_at_most_1s_1_thread": split["seconds"] <= 1.0,  # (b): the second call, after a warm-up
        "10k_start_up_in_first_call_at_most_0.5s_1_thread": split["start_up_in_first_call_s"] <= 0.5,  # (a) - (b)
        "10k_whole_first_call_at_most_1.5s_1_thread": one_thread["10000"]["seconds"] <= 1.5,  # (a)
        "100k_at_most_10s_1_thread": one_thread["100000"]["seconds"] <= 10.0,
        "100k_at_most_0.2x_poisson_disk_1_thread": ratios["100000"]["poisson_disk_over_synthesis_1_thread"] >= 5.0,
    }
    if "1000000" in synthesis:
        results["targets"]["1M_at_most_120s"] = synthesis["1000000"]["seconds"] <= 120.0
        results["targets"]["1M_at_most_1.5GB"] = synthesis["1000000"]["peak_gb"] <= 1.5
    save_results("speed", results)


if __name__ == "__main__":
    main()
