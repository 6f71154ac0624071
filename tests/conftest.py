"""Shared fixtures: small maps and point files made by the tests themselves."""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_variable] = "1"  # tests run single-threaded (torch reads OMP_NUM_THREADS): set before anything loads

from pathlib import Path  # noqa: E402 - after the thread variables

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from patternshop import cli  # noqa: E402
from synthesis.labmap import LabMap  # noqa: E402
from synthesis.mapio import write_tiff  # noqa: E402


def random_map(height: int, width: int, seed: int = 0) -> LabMap:
    """A (height, width) map with uniform random L, a, b over their whole ranges."""
    rng = np.random.default_rng(seed)
    lab = np.stack(
        [rng.uniform(0, 100, (height, width)), rng.uniform(-128, 127, (height, width)), rng.uniform(-128, 127, (height, width))],
        axis=-1,
    )
    return LabMap(lab)


@pytest.fixture
def map_tif(tmp_path: Path) -> Path:
    """A 16-bit CIELAB TIFF of a random 12 x 18 (non-square) map."""
    path = tmp_path / "map.tif"
    write_tiff(random_map(12, 18), path, bits=16)
    return path


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """Run the ``patternshop`` CLI in-process; returns (exit status, stdout, stderr)."""
    try:
        status = cli.main(argv)
    except SystemExit as exc:  # argparse's --help, --version and usage errors
        status = int(exc.code or 0)
    out, err = capsys.readouterr()
    return status, out, err

