"""The --points-per-ink convention (issue 28, deliverable 6): points per unit area of full ink, recorded in a
synthesised .txt file's header and read back by infer and convert; a given --points-per-ink wins."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from helpers import run_cli
from synthesis.conventions import full_ink_points
from synthesis.labmap import LabMap
from synthesis.mapio import read_map, write_tiff
from synthesis.points import PointSet, read_points, write_points
from synthesis.synthesize import point_count, synthesize


def half_dark(height: int, width: int, density: float = 0.6) -> LabMap:
    """A map whose left half has ``density`` (L = 100 (1 - density)) and right half is white; blue noise."""
    lab = np.zeros((height, width, 3), np.float32)
    lab[..., 0] = 100.0
    lab[:, : width // 2, 0] = 100.0 * (1.0 - density)
    lab[..., 1:] = (24.0, -52.0)
    return LabMap(lab)


def dark_half_dot_density(points: PointSet) -> float:
    """Points per unit area in the left (dark) half of the domain."""
    w, h = points.domain
    return np.count_nonzero(points.xy[:, 0] < w / 2) / (w / 2 * h)


def test_a_dark_region_has_the_same_dot_density_on_any_canvas_shape():
    """points_per_ink is per unit area: a square, a wide and a tall map give their dark halves one dot density."""
    densities = []
    for height, width in ((64, 64), (32, 64), (64, 40)):
        lab_map = half_dark(height, width)
        assert point_count(lab_map, 4000) == round(full_ink_points(4000, lab_map.domain) * lab_map.density().mean())
        points = synthesize(lab_map, n=point_count(lab_map, 4000), iterations=0, seed=1).points
        densities.append(dark_half_dot_density(points))
    assert densities == pytest.approx([0.6 * 4000] * 3, rel=0.03)  # measured: within 1 % (the start is density-matched)


def test_synthesize_writes_the_scale_into_a_txt_header(tmp_path: Path, capsys):
    """With --points too, the header records the points per ink at which the map holds the points written."""
    source = tmp_path / "wide.tif"
    write_tiff(half_dark(32, 64), source)
    output = tmp_path / "points.txt"
    status, _, err = run_cli(["synthesize", str(source), str(output), "--points", "900", "--iterations", "1"], capsys)
    assert status == 0, err
    assert "# points_per_ink: " in output.read_text().splitlines()[2]
    points = read_points(output)
    lab_map = read_map(source)
    assert len(points) == 900 and points.domain == pytest.approx((1.0, 0.5))
    assert points.points_per_ink == pytest.approx(900 / (0.5 * lab_map.density().mean()), rel=1e-6)
    assert point_count(lab_map, points.points_per_ink) == 900  # synthesize at the header's scale: the same count
    for suffix in (".csv", ".npy"):  # plain tables: no header, scale unknown
        write_points(points, tmp_path / f"copy{suffix}")
        assert read_points(tmp_path / f"copy{suffix}").points_per_ink is None
    (tmp_path / "bad.txt").write_text("# points_per_ink: -3\n0.1 0.2\n")
    with pytest.raises(Exception, match=r"bad.txt:1: bad points_per_ink comment"):
        read_points(tmp_path / "bad.txt")


def test_infer_reads_the_header_and_a_given_scale_wins(tmp_path: Path, capsys):
    """A stippling synthesised with --points, inferred without flags, holds the synthesised map's ink (within 15 %);
    the same points without the header read washed out; --points-per-ink overrides the header."""
    source = tmp_path / "map.tif"
    write_tiff(half_dark(48, 64, density=0.8), source)
    points_file = tmp_path / "points.txt"
    assert run_cli(["synthesize", str(source), str(points_file), "--points", "2500", "--iterations", "1"], capsys)[0] == 0
    truth = float(read_map(source).density().mean())
    means = {}
    for name, extra in (("header", []), ("given", ["--points-per-ink", "50000"])):  # no flag: the header's scale
        output, report = tmp_path / f"{name}.tif", tmp_path / f"{name}.json"
        status, _, err = run_cli(["infer", str(points_file), str(output), "--symmetries", "1", "--no-denoise",
                                  "--report", str(report), *extra], capsys)
        assert status == 0, err
        means[name] = float(read_map(output).density().mean())
        means[name + "_scale"] = json.loads(report.read_text())["points_per_ink"]
        assert ("from the file's header" in err) == (name == "header")
    assert means["header"] == pytest.approx(truth, rel=0.15)  # measured: within 1 %
    assert means["header_scale"] == pytest.approx(read_points(points_file).points_per_ink, rel=1e-3)
    assert means["given_scale"] == 50_000 and means["given"] < 0.5 * truth  # a wrong scale: washed out


def test_convert_reads_the_header(tmp_path: Path):
    from export.convert import convert_points
    from export.runtime import DEFAULT_MODEL, OnnxModel

    lab_map = half_dark(32, 64, density=0.8)
    points = synthesize(lab_map, n=1500, iterations=0, seed=2).points
    write_points(points, tmp_path / "p.txt")
    (result,) = convert_points([tmp_path / "p.txt"], tmp_path / "out", OnnxModel(DEFAULT_MODEL), workers=1, denoise=False)
    assert result.error is None, result.error
    assert not result.warnings  # the header's scale is what the file says, not a guess to warn about (one line a file)
    assert float(read_map(result.output).density().mean()) == pytest.approx(float(lab_map.density().mean()), rel=0.15)
