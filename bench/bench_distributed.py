"""Overhead of the Dask back end (data_gen.executor): training pairs per second, local pool vs Dask LocalCluster.

The same procedural items (default settings: 8,000 points per ink, 150
iterations, 256 px maps) are made into a fresh folder by
``data_gen.pairs.generate`` with

* ``local``: the local process pool, ``workers=2``;
* ``dask``: ``executor=dask workers=2``, a LocalCluster of 2 worker processes
  (1 thread each) started for the run, as a single-machine user gets it;
* ``dask_warm``: the same LocalCluster kept running between runs and reached
  by its address (``scheduler=...``), as on a cluster: the per-item overhead alone.

Each rate counts the whole run (workers' or cluster's start-up included),
runs alternate between the back ends so that load from other processes hits
them alike, and the median of ``--repeats`` runs is reported with the ratio
to the local pool (target: >= 0.9) and the load average before and after.

``python bench/bench_distributed.py [--items 16] [--repeats 3]``; results in ``out/bench/distributed.json``.
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics
import tempfile
import time

from common import save_results  # bench/ is on sys.path when run as a script

from data_gen.executor import SCHEDULER_CONFIG
from data_gen.pairs import generate
from data_gen.provenance import compose_config

TARGET_RATIO = 0.9


def pairs_per_second(items: int, extra: list[str]) -> float:
    """Pairs per second of one ``generate`` run of ``items`` fresh items (start-up included)."""
    with tempfile.TemporaryDirectory() as folder:
        cfg = compose_config("pairs", [f"out_dir={folder}", f"num_items={items}", "seed=1000", "workers=2", *extra])
        start = time.perf_counter()
        summary = generate(cfg)
        seconds = time.perf_counter() - start
    assert summary["made_now"] == items, summary
    return items / seconds


def main() -> None:
    import dask
    from distributed import LocalCluster

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--items", type=int, default=16, help="pairs per run (default 16)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per back end (default 3)")
    args = parser.parse_args()

    load_before = os.getloadavg()
    rates: dict[str, list[float]] = {"local": [], "dask": [], "dask_warm": []}
    with dask.config.set(SCHEDULER_CONFIG), LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=logging.ERROR,
            scheduler_kwargs={"allowed_failures": 1}) as warm:
        pairs_per_second(2, ["executor=dask", f"scheduler={warm.scheduler_address}"])  # warm-up: imports, numba
        arms = {"local": [], "dask": ["executor=dask"], "dask_warm": ["executor=dask", f"scheduler={warm.scheduler_address}"]}
        for _ in range(args.repeats):
            for name, extra in arms.items():
                rates[name].append(pairs_per_second(args.items, extra))
    load_after = os.getloadavg()
    medians = {name: statistics.median(values) for name, values in rates.items()}
    results = {
        "items_per_run": args.items, "repeats": args.repeats, "cpus": os.cpu_count(),
        "pairs_per_second": {name: round(value, 3) for name, value in medians.items()},
        "runs": {name: [round(value, 3) for value in values] for name, values in rates.items()},
        "ratio_dask_to_local": round(medians["dask"] / medians["local"], 3),
        "ratio_dask_warm_to_local": round(medians["dask_warm"] / medians["local"], 3),
        "target_ratio": TARGET_RATIO,
        "load_average_before": [round(x, 2) for x in load_before], "load_average_after": [round(x, 2) for x in load_after],
    }
    save_results("distributed", results)


if __name__ == "__main__":
    main()
