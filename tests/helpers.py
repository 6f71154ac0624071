"""Helpers shared by test modules, imported as ``from helpers import ...``.

A plain module, not the conftest: pytest puts this folder on ``sys.path`` (its
default "prepend" import mode, the folder having no ``__init__.py``), so the
import works under ``pytest`` and ``python -m pytest`` alike, from any working
directory. Fixtures stay in ``conftest.py``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from patternshop import cli
from synthesis.labmap import LabMap

ROOT = Path(__file__).resolve().parent.parent


def random_map(height: int, width: int, seed: int = 0) -> LabMap:
    """A (height, width) map with uniform random L, a, b over their whole ranges."""
    rng = np.random.default_rng(seed)
    lab = np.stack(
        [rng.uniform(0, 100, (height, width)), rng.uniform(-128, 127, (height, width)), rng.uniform(-128, 127, (height, width))],
        axis=-1,
    )
    return LabMap(lab)


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """Run the ``patternshop`` CLI in-process; returns (exit status, stdout, stderr)."""
    try:
        status = cli.main(argv)
    except SystemExit as exc:  # argparse's --help, --version and usage errors
        status = int(exc.code or 0)
    out, err = capsys.readouterr()
    return status, out, err


def one_line_error(err: str, *fragments: str) -> str:
    """The single stderr line of a refused command (warnings aside), checked for ``fragments``."""
    lines = [line for line in err.strip().splitlines() if "warning:" not in line]
    assert len(lines) == 1, err
    assert "internal error" not in lines[0] and "unrecognized arguments" not in lines[0], lines[0]
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def fresh_python_lines(code: str, timeout: float = 300) -> list[str]:
    """The lines ``code`` prints when a fresh Python runs it in the repository root (what it imports is its own);
    a non-zero exit fails the test with its stderr."""
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, result.stderr
    return result.stdout.splitlines()
