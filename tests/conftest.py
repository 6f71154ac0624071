"""Shared fixtures: small maps and point files made by the tests themselves."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from patternshop import cli
from synthesis.labmap import LabMap
from synthesis.mapio import write_tiff


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
