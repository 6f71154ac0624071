"""The bundled example maps: present, reproducible by their script, and as described."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from synthesis.mapio import read_map

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("examples")
    subprocess.run([sys.executable, str(EXAMPLES / "make_examples.py"), f"out_dir={out}"], check=True, capture_output=True)
    return out


@pytest.mark.parametrize("name", ["logo", "gradient"])
def test_bundled_maps_match_their_script(name, regenerated):
    bundled, fresh = read_map(EXAMPLES / f"{name}.tif"), read_map(regenerated / f"{name}.tif")
    np.testing.assert_array_equal(bundled.lab, fresh.lab)
    assert (regenerated / f"{name}_preview.png").stat().st_size > 0


def test_logo_has_sharp_correlation_regions_and_varying_density():
    logo = read_map(EXAMPLES / "logo.tif")
    assert logo.domain == pytest.approx((1.0, 2.0 / 3.0))  # non-square
    colours, counts = np.unique(np.round(logo.ab.reshape(-1, 2), 2), axis=0, return_counts=True)
    assert len(colours) == 3 and counts.min() > 0.05 * counts.sum()  # three regions, hard edges: no blends
    density = logo.density()
    assert density.min() < 0.15 and density.max() > 0.8 and len(np.unique(np.round(density, 3))) > 50


def test_gradient_is_smooth():
    gradient = read_map(EXAMPLES / "gradient.tif")
    density = gradient.density()
    assert np.all(np.diff(density, axis=1) > 0)  # rises left to right
    assert np.abs(np.diff(gradient.ab, axis=0)).max() < 1.0  # no correlation edges
    assert np.abs(gradient.ab[0] - gradient.ab[-1]).max() > 50  # but the correlation does change


def test_bundled_points_match_their_script(regenerated):
    """logo_points.txt (the demo's input) is the script's synthesis of logo.tif: same count and domain, same layout."""
    from synthesis.points import read_points

    bundled, fresh = read_points(EXAMPLES / "logo_points.txt"), read_points(regenerated / "logo_points.txt")
    assert len(bundled) == len(fresh) and bundled.domain == fresh.domain
    # bit-identical on one machine; across machines float rounding may move points, so compare coarse counts
    bins = [np.linspace(0, 1, 7), np.linspace(0, 2 / 3, 5)]
    counts = [np.histogram2d(p.xy[:, 0], p.xy[:, 1], bins)[0] for p in (bundled, fresh)]
    assert np.abs(counts[0] - counts[1]).max() <= 0.1 * counts[0].max()
