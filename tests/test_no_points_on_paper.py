"""No point where the map has no ink (issue 27): silhouettes, text, thin and extreme-aspect maps, every preset;
and a run whose figures are absurd says so.

"Far from ink" is measured independently of the synthesiser: the distance from the pixel a point lies on to the
nearest pixel with ink (density > 0; scipy's Euclidean distance transform, pixel centre to pixel centre), against
half the local spacing ``r_max = 2 sqrt(A / (2 sqrt(3) n))`` (SPEC §2.2) of the n points spread over the ink,
``A = sum(density) x pixel area`` (for black ink on white: the inked area).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image, ImageDraw, ImageFont
from scipy import ndimage

from helpers import run_cli
from synthesis.errors import PatternshopWarning
from synthesis.fields import MapFields, nearest_ink
from synthesis.labmap import LabMap
from synthesis.mapio import write_tiff
from synthesis.palette import load_palette
from synthesis.step_fast import hold_in_ink
from synthesis.synthesize import absurd_run, hold_in_ink_reference, misplaced_share, synthesize

PALETTE = load_palette()


def ink_map(density: np.ndarray, preset: str) -> LabMap:
    """A map of ``density`` (H, W) in [0, 1] (0: white paper) in the colour of ``preset``."""
    a, b = PALETTE.preset_ab()[preset]
    density = np.asarray(density, np.float32)
    return LabMap(np.stack([100.0 * (1.0 - density), np.full_like(density, a), np.full_like(density, b)], axis=-1))


def disc(size: int, radius: float) -> np.ndarray:
    """(size, size) black disc of ``radius`` pixels at the centre, white elsewhere."""
    y, x = np.mgrid[0:size, 0:size] + 0.5
    return ((x - size / 2) ** 2 + (y - size / 2) ** 2 < radius**2).astype(np.float32)


def text(word: str, width: int, height: int, size: int) -> np.ndarray:
    """(height, width) ``word`` rendered in black with Pillow's default font (anti-aliased grey edges)."""
    image = Image.new("L", (width, height), 255)
    ImageDraw.Draw(image).text((4, 4), word, fill=0, font=ImageFont.load_default(size=size))
    return 1.0 - np.asarray(image, np.float32) / 255.0


def off_ink(density: np.ndarray, xy: np.ndarray) -> tuple[int, int]:
    """(points farther than half a local spacing from ink, points on a pixel without ink) of points xy (n, 2)."""
    height, width = density.shape
    side = max(height, width)
    ink = density > 0
    distance = ndimage.distance_transform_edt(~ink) / side  # map units
    spacing = 2.0 * math.sqrt(float(density.sum()) / side**2 / (2.0 * math.sqrt(3.0) * len(xy)))
    col = np.clip((xy[:, 0] * side).astype(int), 0, width - 1)
    row = np.clip((xy[:, 1] * side).astype(int), 0, height - 1)
    at = distance[row, col]
    return int(np.sum(at > 0.5 * spacing)), int(np.sum(at > 0))


def assert_on_ink(density: np.ndarray, preset: str, n: int) -> None:
    xy = synthesize(ink_map(density, preset), n=n, seed=1).points.xy
    assert off_ink(density, xy) == (0, 0)


@pytest.mark.parametrize("preset", sorted(PALETTE.preset_ab()))
def test_no_point_leaves_a_disc(preset: str):
    # before: a 256 px disc lost 267 (blue), 539 (green), 275 (red) of 8,624 points to a ring out in the white
    assert_on_ink(disc(80, 20.0), preset, 500)


@pytest.mark.parametrize("preset", ["blue", "red"])
def test_no_point_leaves_rendered_text(preset: str):
    assert_on_ink(text("Ink", 120, 56, 44), preset, 400)


def test_no_point_leaves_a_thin_line():
    line = np.zeros((96, 96), np.float32)
    rows = np.arange(8, 88)
    line[rows, rows] = line[rows, rows + 1] = 1.0  # a diagonal two pixels wide
    assert_on_ink(line, "blue", 60)


@pytest.mark.parametrize("shape", [(1, 10000), (10000, 1)])
def test_extreme_aspect_maps_spread_points_along_the_long_side(shape: tuple[int, int]):
    # before: every point went to the last (or first) 0.07 % of the long side (the start had no cell inside the domain)
    n, bins = 500, 10
    points = synthesize(ink_map(np.full(shape, 0.5), "blue"), n=n).points
    axis = int(shape[0] > shape[1])
    counts = np.histogram(points.xy[:, axis], bins=bins, range=(0.0, points.domain[axis]))[0]
    expected = n / bins
    assert np.abs(counts - expected).max() <= 3.0 * math.sqrt(expected), counts  # a Poisson sample's spread


def test_spacing_is_bounded_where_the_map_has_no_ink():
    fields = MapFields.build(ink_map(disc(64, 12.0), "blue"), 300, PALETTE)
    ink = disc(64, 12.0) > 0
    assert fields.spacing[~ink].max() <= fields.spacing[ink].max()  # white takes the nearest ink's spacing


def test_hold_sends_every_point_onto_ink_and_matches_the_reference():
    lab_map = ink_map(disc(64, 10.0), "blue")
    nearest, side_px = nearest_ink(lab_map.density())
    rng = np.random.default_rng(3)
    xy = rng.random((4000, 2))
    xy[:50] = 0.5 + rng.normal(0.0, 11.0 / 64, (50, 2)).clip(-0.49, 0.49)  # near the disc's edge
    first = rng.normal(size=xy.shape)
    ours, ours_first = xy.copy(), first.copy()
    hold_in_ink(ours, ours_first, nearest, side_px)
    plain, plain_first = xy.copy(), first.copy()
    hold_in_ink_reference(plain, plain_first, nearest, side_px)
    np.testing.assert_array_equal(ours, plain)
    np.testing.assert_array_equal(ours_first, plain_first)
    assert off_ink(lab_map.density(), ours) == (0, 0)
    on_ink = lab_map.density()[(xy[:, 1] * 64).astype(int), (xy[:, 0] * 64).astype(int)] > 0
    np.testing.assert_array_equal(ours[on_ink], xy[on_ink])  # points on ink are left alone
    assert (ours_first[~on_ink] != first[~on_ink]).any()  # a point sent back reverses its momentum


def test_absurd_figures_warn_and_sound_ones_do_not():
    uniform = ink_map(np.full((1, 10000), 0.5), "blue")
    spread = np.stack([(np.arange(2000) + 0.5) / 2000, np.full(2000, 5e-5)], axis=1)
    collapsed = np.stack([np.full(2000, 0.9996), np.full(2000, 5e-5)], axis=1)  # the 1 x 10000 map before its fix
    assert misplaced_share(uniform, spread) < 0.01 and misplaced_share(uniform, collapsed) == pytest.approx(7 / 8)
    assert absurd_run(2.0e3, 0.1, 0.05) == [] and absurd_run(1.7e-5, 0.66, 0.05) == []  # a start within the dead zones
    with pytest.warns(PatternshopWarning) as caught:
        assert len(absurd_run(9.6e10, 2.4e10, 7 / 8)) == 1
        assert len(absurd_run(1.0, 2.4e10, 0.0)) == 1
        assert len(absurd_run(1.0, math.nan, 0.0)) == 1
    assert "88% of the points would have to move" in str(caught[0].message)
    assert "final loss 2.4e+10" in str(caught[1].message) and "final loss nan" in str(caught[2].message)


def test_synthesize_reports_an_absurd_run_on_stderr_and_in_the_report(tmp_path, capsys, monkeypatch):
    path = tmp_path / "disc.tif"
    write_tiff(ink_map(disc(48, 12.0), "blue"), path)
    argv = ["synthesize", str(path), str(tmp_path / "p.txt"), "--points", "150", "--iterations", "20", "--no-progress"]
    status, _, err = run_cli([*argv, "--report", str(tmp_path / "sound.json")], capsys)
    assert status == 0 and "warning" not in err
    assert json.loads((tmp_path / "sound.json").read_text())["warnings"] == []

    import synthesis.synthesize

    monkeypatch.setattr(synthesis.synthesize, "final_loss", lambda *args: 2.4e10)
    status, _, err = run_cli([*argv, "--report", str(tmp_path / "absurd.json")], capsys)
    assert status == 0
    assert json.loads((tmp_path / "absurd.json").read_text())["warnings"] == [
        line.removeprefix("patternshop: warning: ") for line in err.splitlines() if "warning:" in line]
    assert "final loss 2.4e+10" in err
