"""Shared fixtures: small maps and point files made by the tests themselves."""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_variable] = "1"  # tests run single-threaded (torch reads OMP_NUM_THREADS): set before anything loads

from pathlib import Path  # noqa: E402 - after the thread variables

import pytest  # noqa: E402

from helpers import random_map  # noqa: E402 - shared helpers live in tests/helpers.py (tests import them from there)
from synthesis.mapio import write_tiff  # noqa: E402


@pytest.fixture
def map_tif(tmp_path: Path) -> Path:
    """A 16-bit CIELAB TIFF of a random 12 x 18 (non-square) map."""
    path = tmp_path / "map.tif"
    write_tiff(random_map(12, 18), path, bits=16)
    return path
