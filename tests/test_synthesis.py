"""Edge-aware PCF estimator and synthesiser: unbiasedness, convergence, density, determinism, errors."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch

from patternshop import cli
from synthesis.edgepcf import estimate, find_neighbourhoods, loss_and_gradient
from synthesis.errors import PatternshopError
from synthesis.fields import MapFields
from synthesis.labmap import LabMap
from synthesis.mapio import write_tiff
from synthesis.palette import load_palette
from synthesis.pcf import stationary_pcf
from synthesis.synthesize import initial_points, point_count, synthesize
from synthesis.tone import density_fidelity


def constant_map(L: float, a: float, b: float, size: tuple[int, int] = (48, 48)) -> LabMap:
    return LabMap(np.broadcast_to(np.array([L, a, b], np.float32), size + (3,)))


def split_map() -> LabMap:
    """Left half light blue noise, right half dark red (clustered): a density and a correlation edge."""
    palette = load_palette()
    lab = np.zeros((48, 64, 3), np.float32)
    lab[:, :32] = [80.0, *palette.preset_ab()["blue"]]
    lab[:, 32:] = [40.0, *palette.preset_ab()["red"]]
    return LabMap(lab)


def inhomogeneous_poisson(lab_map: LabMap, n: int, seed: int) -> torch.Tensor:
    return torch.from_numpy(initial_points(lab_map, n, np.random.default_rng(seed)).astype(np.float32))


def test_estimator_is_unbiased_for_poisson_at_interior_border_and_edge():
    lab_map = split_map()
    fields = MapFields.build(lab_map, 3000, load_palette())
    w, h = fields.domain
    groups = {"interior": [], "border": [], "edge": []}
    for seed in range(4):
        xy = inhomogeneous_poisson(lab_map, 3000, seed)
        g = estimate(fields, xy, find_neighbourhoods(fields, xy, torch.arange(3000))).mean(dim=1).numpy()
        x, y = xy[:, 0].numpy(), xy[:, 1].numpy()
        margin = 0.04
        border = (x < margin) | (y < margin) | (x > w - margin) | (y > h - margin)
        edge = np.abs(x - w / 2) < margin
        groups["border"].append(g[border & ~edge])
        groups["edge"].append(g[edge & ~border])
        groups["interior"].append(g[~border & ~edge])
    for name, values in groups.items():
        assert abs(np.concatenate(values).mean() - 1.0) < 0.1, name


def test_gradient_matches_finite_differences():
    lab_map = split_map()
    fields = MapFields.build(lab_map, 500, load_palette())
    xy = inhomogeneous_poisson(lab_map, 500, 0).double().float()
    hood = find_neighbourhoods(fields, xy, torch.arange(500))
    _, gradient = loss_and_gradient(fields, xy, hood)
    for index, axis in [(3, 0), (77, 1), (250, 0)]:
        step = 2e-4
        plus, minus = xy.clone(), xy.clone()
        plus[index, axis] += step
        minus[index, axis] -= step
        numeric = (loss_and_gradient(fields, plus, hood)[0] - loss_and_gradient(fields, minus, hood)[0]) / (2 * step)
        assert numeric == pytest.approx(float(gradient[index, axis]), rel=0.1, abs=1e-4)


@pytest.fixture(scope="module")
def blue_result():
    palette = load_palette()
    return synthesize(constant_map(50.0, *palette.preset_ab()["blue"]), n=1500, seed=3)


def test_synthesis_reaches_the_target_pcf_and_a_poisson_start_does_not(blue_result):
    palette = load_palette()
    target = palette.pcf(*palette.preset_ab()["blue"])
    realised = stationary_pcf(blue_result.points.xy, blue_result.points.domain, periodic=False)
    start = initial_points(constant_map(50.0, 0, 0), 1500, np.random.default_rng(3))
    poisson = stationary_pcf(start, (1.0, 1.0), periodic=False)
    assert np.abs(realised - target).mean() < 0.05
    assert np.abs(poisson - target).mean() > 0.15
    assert blue_result.losses[-1] < 0.1 * blue_result.losses[0]


def test_synthesis_is_deterministic_for_a_seed(blue_result):
    palette = load_palette()
    again = synthesize(constant_map(50.0, *palette.preset_ab()["blue"]), n=1500, seed=3)
    np.testing.assert_array_equal(again.points.xy, blue_result.points.xy)
    other = synthesize(constant_map(50.0, *palette.preset_ab()["blue"]), n=1500, seed=4, iterations=5)
    assert not np.array_equal(other.points.xy, blue_result.points.xy)


def test_density_follows_a_two_level_map():
    lab = np.zeros((40, 80, 3), np.float32)
    lab[:, :40, 0], lab[:, 40:, 0] = 85.0, 40.0  # density 0.15 | 0.6
    lab[..., 1:] = load_palette().preset_ab()["blue"]
    result = synthesize(LabMap(lab), n=2000, seed=0, iterations=120)
    x = result.points.xy[:, 0]
    ratio = np.sum(x > 0.5) / np.sum(x < 0.5)
    assert ratio == pytest.approx(4.0, rel=0.15)
    assert density_fidelity(result.points, LabMap(lab))["ssim"] > 0.5


def test_point_count_and_bad_maps():
    assert point_count(constant_map(50.0, 0, 0)) == 25_000
    with pytest.raises(PatternshopError, match="white everywhere"):
        point_count(constant_map(100.0, 0, 0))
    with pytest.raises(PatternshopError, match="white everywhere"):
        synthesize(constant_map(100.0, 0, 0), n=100)
    with pytest.raises(Exception, match="NaN"):
        LabMap(np.full((4, 4, 3), np.nan))


def test_cli_synthesize_writes_points_png_svg_and_report(tmp_path, capsys):
    palette = load_palette()
    map_path = tmp_path / "m.tif"
    write_tiff(constant_map(60.0, *palette.preset_ab()["green"], size=(32, 48)), map_path)
    out = tmp_path / "p.txt"
    argv = ["synthesize", str(map_path), str(out), "--points", "600", "--iterations", "40", "--dot-sizes",
            "--png", str(tmp_path / "p.png"), "--svg", str(tmp_path / "p.svg"), "--report", str(tmp_path / "r.json")]
    assert cli.main(argv) == 0
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["n"] == 600 and report["iterations"] == 40 and report["seconds"] > 0 and "final_loss" in report
    circles = ET.parse(tmp_path / "p.svg").getroot().findall(".//{http://www.w3.org/2000/svg}circle")
    assert len(circles) == 600
    assert (tmp_path / "p.png").stat().st_size > 0
    assert len(out.read_text().splitlines()) == 602  # two header comments + points (with radii)


def test_cli_synthesize_white_map_is_one_line_error(tmp_path, capsys):
    map_path = tmp_path / "white.tif"
    write_tiff(constant_map(100.0, 0, 0), map_path)
    assert cli.main(["synthesize", str(map_path), str(tmp_path / "p.txt")]) == 2
    err = capsys.readouterr().err
    assert "white everywhere" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "p.txt").exists()


def test_large_maps_are_averaged_down_for_the_fields():
    palette = load_palette()
    lab = np.zeros((400, 600, 3), np.float32)
    lab[:, :300] = [80.0, *palette.preset_ab()["blue"]]
    lab[:, 300:] = [40.0, *palette.preset_ab()["blue"]]
    fields = MapFields.build(LabMap(lab), 2000, palette)
    assert fields.intensity.shape[:2] == (171, 256) and fields.side_px == 256
    assert fields.domain == pytest.approx((1.0, 2.0 / 3.0))
    left, right = fields.intensity[85, 10, 0], fields.intensity[85, 245, 0]
    assert float(right / left) == pytest.approx(3.0, rel=1e-3)  # density 0.2 | 0.6
