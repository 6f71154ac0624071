"""Run every benchmark in ``bench/`` (files ``bench_*.py``) and collect their results.

Each benchmark is a script run in its own process (so one cannot slow another
through leftover threads or memory); it prints a human-readable report and may
write JSON results under ``out/bench/``. Run with ``make bench``.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent


def main() -> int:
    scripts = sorted(BENCH_DIR.glob("bench_*.py"))
    if not scripts:
        print("no benchmarks in bench/ yet")
        return 0
    failed = []
    for script in scripts:
        print(f"== {script.name}", flush=True)
        start = time.perf_counter()
        status = subprocess.call([sys.executable, str(script)], cwd=BENCH_DIR.parent)
        print(f"== {script.name}: exit {status}, {time.perf_counter() - start:.1f} s", flush=True)
        if status:
            failed.append(script.name)
    if failed:
        print("failed: " + ", ".join(failed), file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
