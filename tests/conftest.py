"""Shared fixtures: small maps and point files made by the tests themselves."""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_variable] = "1"  # tests run single-threaded (torch reads OMP_NUM_THREADS): set before anything loads

from pathlib import Path  # noqa: E402 - after the thread variables

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from helpers import random_map  # noqa: E402 - shared helpers live in tests/helpers.py (tests import them from there)
from synthesis.mapio import write_tiff  # noqa: E402
from synthesis.points import PointSet, write_points  # noqa: E402


@pytest.fixture
def map_tif(tmp_path: Path) -> Path:
    """A 16-bit CIELAB TIFF of a random 12 x 18 (non-square) map."""
    path = tmp_path / "map.tif"
    write_tiff(random_map(12, 18), path, bits=16)
    return path


@pytest.fixture
def small_map(tmp_path: Path) -> Path:
    path = tmp_path / "small.tif"
    write_tiff(random_map(24, 32), path)
    return path


@pytest.fixture
def points_file(tmp_path: Path) -> Path:
    path = tmp_path / "points.txt"
    write_points(PointSet(np.random.default_rng(0).random((500, 2))), path)
    return path
