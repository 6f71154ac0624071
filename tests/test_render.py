"""Rendering point patterns (SPEC.md section 3, "Outputs of synthesis"): synthesis.render.

Covers the dot raster (sizes, areas, positions with y down, union of overlaps,
anti-aliasing), the PNG and SVG outputs (sizes, namespace, millimetre scaling,
pen-plotter mode, radius clamping, atomic writes), the blurred tone image and
the errors for bad arguments.
"""

from __future__ import annotations

import math
import re
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import synthesis.render as render
from synthesis.errors import PatternshopError
from synthesis.points import PointSet
from synthesis.render import default_radius, rasterize_dots, render_png, tone_image, write_svg

SVG = "{http://www.w3.org/2000/svg}"


def dot(x: float, y: float, r: float, domain: tuple[float, float] = (1.0, 1.0)) -> PointSet:
    return PointSet(np.array([[x, y]]), domain, np.array([r]))


def centroid(image: np.ndarray) -> tuple[float, float]:
    """Coverage-weighted centre (x, y) in pixels; pixel (i, j) is centred at (j + .5, i + .5)."""
    rows, cols = np.indices(image.shape) + 0.5
    return float((cols * image).sum() / image.sum()), float((rows * image).sum() / image.sum())


def jittered_grid(k: int, seed: int = 0) -> PointSet:
    """k x k points, one uniformly placed in each cell of a k x k grid over the unit square."""
    rng = np.random.default_rng(seed)
    cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), axis=-1).reshape(-1, 2)
    return PointSet((cells + rng.uniform(0, 1, cells.shape)) / k)


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def parse_svg(path: Path) -> tuple[ET.Element, ET.Element, list[ET.Element]]:
    """(root, group, circles) of an SVG written by write_svg."""
    root = ET.parse(path).getroot()
    (group,) = root.findall(f"{SVG}g")
    return root, group, group.findall(f"{SVG}circle")


def circle_values(circles: list[ET.Element], name: str) -> np.ndarray:
    return np.array([float(c.get(name)) for c in circles])


# --------------------------------------------------------------------------- raster


def test_default_radius_is_a_fraction_of_the_mean_spacing() -> None:
    points = PointSet(np.zeros((50, 2)), (1.0, 0.5))
    assert default_radius(points) == pytest.approx(0.3 * math.sqrt(0.5 / 50))


@pytest.mark.parametrize(
    ("domain", "width", "shape"),
    [((1.0, 1.0), 64, (64, 64)), ((1.0, 0.5), 64, (32, 64)), ((0.6, 1.0), 30, (50, 30)), ((1.0, 0.667), 384, (256, 384))],
)
def test_raster_shape_dtype_and_range(domain: tuple[float, float], width: int, shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(1)
    points = PointSet(rng.uniform(0, 1, (300, 2)) * domain, domain)
    coverage = rasterize_dots(points, width)
    assert coverage.shape == shape
    assert coverage.dtype == np.float32
    assert coverage.min() >= 0 and coverage.max() <= 1
    assert 0 < coverage.mean() < 1


def test_single_dot_has_the_area_of_its_disk() -> None:
    coverage = rasterize_dots(dot(0.5, 0.5, 0.1), 200)
    assert coverage.sum() == pytest.approx(math.pi * 20**2, rel=0.01)
    assert coverage.max() == 1.0


def test_tiny_dot_keeps_its_area_thanks_to_supersampling() -> None:
    coverage = rasterize_dots(dot(0.5037, 0.4981, 0.004), 500, supersample=8)  # radius 2 px
    assert coverage.sum() == pytest.approx(math.pi * 2**2, rel=0.05)


def test_dot_is_centred_at_its_point_with_y_down() -> None:
    # a non-square domain, the point near the top-left: y = 0.15 is near row 0
    coverage = rasterize_dots(dot(0.3, 0.15, 0.05, domain=(1.0, 0.8)), 200)
    assert coverage.shape == (160, 200)
    x, y = centroid(coverage)
    assert (x, y) == pytest.approx((60.0, 30.0), abs=0.05)
    assert coverage[:60].sum() == pytest.approx(coverage.sum())


def test_tall_domain_scales_both_axes_alike() -> None:
    coverage = rasterize_dots(dot(0.25, 0.9, 0.05, domain=(0.5, 1.0)), 100)  # 200 pixels per unit
    assert coverage.shape == (200, 100)
    assert centroid(coverage) == pytest.approx((50.0, 180.0), abs=0.05)
    assert coverage.sum() == pytest.approx(math.pi * 10**2, rel=0.02)


def test_points_without_radii_get_the_default_radius() -> None:
    points = PointSet(np.array([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75]]))
    radius_px = default_radius(points) * 100  # 0.15 of the unit square: the disks do not touch
    assert rasterize_dots(points, 100).sum() == pytest.approx(4 * math.pi * radius_px**2, rel=0.01)


def test_overlapping_dots_form_their_union() -> None:
    one = rasterize_dots(dot(0.5, 0.5, 0.2), 100)
    same = PointSet(np.array([[0.5, 0.5], [0.5, 0.5]]), radius=np.array([0.2, 0.2]))
    np.testing.assert_array_equal(rasterize_dots(same, 100), one)
    # two disks of radius r whose centres are r apart: union = 2 pi r^2 - lens
    r, d = 20.0, 20.0
    lens = 2 * r**2 * math.acos(d / (2 * r)) - d / 2 * math.sqrt(4 * r**2 - d**2)
    pair = PointSet(np.array([[0.4, 0.5], [0.6, 0.5]]), radius=np.array([0.2, 0.2]))
    coverage = rasterize_dots(pair, 100)
    assert coverage.max() == 1.0
    assert coverage.sum() == pytest.approx(2 * math.pi * r**2 - lens, rel=0.01)


def test_supersampling_anti_aliases_the_edges() -> None:
    points = dot(0.5, 0.5, 0.2)
    hard = rasterize_dots(points, 50, supersample=1)
    assert set(np.unique(hard)) <= {0.0, 1.0}
    soft = rasterize_dots(points, 50, supersample=4)
    assert np.any((soft > 0) & (soft < 1))
    np.testing.assert_allclose(soft * 16, np.rint(soft * 16), atol=1e-5)  # fractions of 4 x 4 samples


def test_dots_are_clipped_at_the_domain_edges_and_zero_radius_draws_nothing() -> None:
    corner = rasterize_dots(dot(0.0, 0.0, 0.2), 100)
    assert corner.sum() == pytest.approx(math.pi * 20**2 / 4, rel=0.01)
    assert corner[0, 0] == 1.0 and corner[-1, -1] == 0.0
    assert rasterize_dots(dot(0.5, 0.5, 0.0), 100).sum() == 0
    assert rasterize_dots(PointSet(np.empty((0, 2))), 10).sum() == 0


def test_huge_dots_and_small_chunks_give_the_same_raster(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(2)
    huge = PointSet(rng.uniform(0, 1, (40, 2)), radius=np.full(40, 2.0))  # every dot covers everything
    np.testing.assert_array_equal(rasterize_dots(huge, 600), 1.0)
    mixed = PointSet(rng.uniform(0, 1, (500, 2)), radius=rng.uniform(0, 0.1, 500))
    whole = rasterize_dots(mixed, 100)
    monkeypatch.setattr(render, "_ROWS_PER_CHUNK", 50)  # many chunks; some dots span more rows than one
    np.testing.assert_array_equal(rasterize_dots(mixed, 100), whole)
    np.testing.assert_array_equal(rasterize_dots(huge, 60), 1.0)


def test_rasterize_is_fast_for_many_points() -> None:
    points = PointSet(np.random.default_rng(3).uniform(0, 1, (100_000, 2)))
    start = time.perf_counter()
    coverage = rasterize_dots(points, 1024)
    assert time.perf_counter() - start < 5.0  # about 0.5 s on a 2-core machine
    # random points, coverage 1 - exp(-n pi r^2) of the union of dots (minus edge effects)
    assert coverage.mean() == pytest.approx(1 - math.exp(-math.pi * 0.3**2), rel=0.03)


# --------------------------------------------------------------------------- PNG


def test_png_is_greyscale_black_dots_on_white(tmp_path: Path) -> None:
    path = tmp_path / "dots.png"
    render_png(dot(0.25, 0.1, 0.05, domain=(1.0, 0.5)), path, width_px=200)
    with Image.open(path) as image:
        assert image.format == "PNG" and image.mode == "L"
        assert image.size == (200, 100)
        grey = np.asarray(image)
    assert grey[20, 50] == 0  # row y * 200, column x * 200
    assert grey[80, 150] == 255
    assert grey.min() == 0 and grey.max() == 255
    assert listing(tmp_path) == ["dots.png"]


def test_png_failure_leaves_no_file_and_keeps_the_old_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken_save(self: Image.Image, fp: Path, *args: object, **kwargs: object) -> None:
        Path(fp).write_bytes(b"\x89PNG half")
        raise OSError("disk full")

    old = tmp_path / "old.png"
    old.write_bytes(b"previous")
    monkeypatch.setattr(Image.Image, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        render_png(dot(0.5, 0.5, 0.1), tmp_path / "new.png", width_px=20)
    with pytest.raises(OSError, match="disk full"):
        render_png(dot(0.5, 0.5, 0.1), old, width_px=20)
    assert listing(tmp_path) == ["old.png"]
    assert old.read_bytes() == b"previous"


# --------------------------------------------------------------------------- SVG


def test_svg_document_size_namespace_and_scaling(tmp_path: Path) -> None:
    path = tmp_path / "dots.svg"
    xy = np.array([[0.0, 0.0], [1.0, 0.5], [0.25, 0.1], [0.123456, 0.4]])
    write_svg(PointSet(xy, (1.0, 0.5), np.array([0.01, 0.02, 0.005, 0.001])), path, width_mm=200)
    root, group, circles = parse_svg(path)
    assert root.tag == f"{SVG}svg"
    assert (root.get("width"), root.get("height")) == ("200mm", "100mm")
    assert [float(v) for v in root.get("viewBox").split()] == [0, 0, 200, 100]
    assert group.get("fill") == "black" and group.get("stroke") is None
    assert len(circles) == 4
    np.testing.assert_allclose(circle_values(circles, "cx"), xy[:, 0] * 200, atol=5e-5)
    np.testing.assert_allclose(circle_values(circles, "cy"), xy[:, 1] * 200, atol=5e-5)  # y down, as in the domain
    assert (circles[1].get("cx"), circles[1].get("cy")) == ("200", "100")  # (w, h): the far corner
    np.testing.assert_allclose(circle_values(circles, "r"), [2, 4, 1, 0.2], atol=5e-5)
    numbers = re.findall(r'"(-?[0-9.]+)(?:mm)?"', path.read_text())
    assert numbers and all(len(n.partition(".")[2]) <= 4 for n in numbers)
    assert "24.6912" in path.read_text()  # 0.123456 * 200, rounded to 4 decimals
    assert listing(tmp_path) == ["dots.svg"]


def test_svg_of_a_tall_domain_has_its_aspect_ratio(tmp_path: Path) -> None:
    path = tmp_path / "tall.svg"
    points = PointSet(np.random.default_rng(4).uniform(0, 0.6, (25, 2)), (0.6, 1.0))
    write_svg(points, path, width_mm=150)
    root, _, circles = parse_svg(path)
    assert (root.get("width"), root.get("height")) == ("150mm", "250mm")
    assert root.get("viewBox") == "0 0 150 250"
    assert len(circles) == 25
    # no radii: the default radius, scaled to millimetres
    np.testing.assert_allclose(circle_values(circles, "r"), default_radius(points) * 250, atol=5e-5)


def test_svg_pen_mode_strokes_and_widens_small_circles(tmp_path: Path) -> None:
    path = tmp_path / "pen.svg"
    points = PointSet(np.array([[0.2, 0.2], [0.8, 0.8]]), radius=np.array([0.001, 0.01]))  # 0.1 mm and 1 mm
    write_svg(points, path, width_mm=100, pen_width_mm=0.5)
    _, group, circles = parse_svg(path)
    assert group.get("fill") == "none"
    assert group.get("stroke") == "black" and float(group.get("stroke-width")) == 0.5
    np.testing.assert_allclose(circle_values(circles, "r"), [0.25, 1.0])


def test_svg_radii_are_clamped_into_min_and_max(tmp_path: Path) -> None:
    path = tmp_path / "clamped.svg"
    points = PointSet(np.full((3, 2), 0.5), radius=np.array([0.001, 0.01, 0.1]))  # 0.2, 2 and 20 mm
    write_svg(points, path, min_radius_mm=0.5, max_radius_mm=5)
    np.testing.assert_allclose(circle_values(parse_svg(path)[2], "r"), [0.5, 2, 5])
    write_svg(points, path, pen_width_mm=0.3, max_radius_mm=5)
    np.testing.assert_allclose(circle_values(parse_svg(path)[2], "r"), [0.2, 2, 5])


def test_svg_failure_leaves_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    original = Path.write_text

    def broken_write_text(self: Path, text: str, *args: object, **kwargs: object) -> int:
        original(self, text[: len(text) // 2], *args, **kwargs)
        raise OSError("disk full")

    monkeypatch.setattr(Path, "write_text", broken_write_text)
    with pytest.raises(OSError, match="disk full"):
        write_svg(dot(0.5, 0.5, 0.1), tmp_path / "dots.svg")
    assert listing(tmp_path) == []


# --------------------------------------------------------------------------- tone


def test_tone_of_a_dense_uniform_stipple_is_flat() -> None:
    points = jittered_grid(64)
    coverage = rasterize_dots(points, 256)
    tone = tone_image(points, 256, blur_px=6.0)
    assert tone.shape == (256, 256) and tone.dtype == np.float32
    interior = tone[32:-32, 32:-32]
    assert interior.std() < 0.05 * interior.mean()
    assert coverage[32:-32, 32:-32].std() > 5 * interior.std()  # the blur did the flattening
    assert interior.mean() == pytest.approx(coverage.mean(), rel=0.05)


def test_tone_without_blur_is_the_raster() -> None:
    points = jittered_grid(8)
    np.testing.assert_allclose(tone_image(points, 40, blur_px=0), rasterize_dots(points, 40))


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    "call",
    [
        pytest.param(lambda p, d: rasterize_dots(p, 0), id="width-0"),
        pytest.param(lambda p, d: rasterize_dots(p, 10.5), id="width-float"),
        pytest.param(lambda p, d: rasterize_dots(p, 10, supersample=0), id="supersample-0"),
        pytest.param(lambda p, d: render_png(p, d / "x.png", width_px=-3), id="png-width"),
        pytest.param(lambda p, d: tone_image(p, 10, blur_px=-1), id="blur-negative"),
        pytest.param(lambda p, d: write_svg(p, d / "x.svg", width_mm=0), id="width-mm-0"),
        pytest.param(lambda p, d: write_svg(p, d / "x.svg", width_mm=-5), id="width-mm-negative"),
        pytest.param(lambda p, d: write_svg(p, d / "x.svg", width_mm=math.inf), id="width-mm-inf"),
        pytest.param(lambda p, d: write_svg(p, d / "x.svg", pen_width_mm=0), id="pen-0"),
        pytest.param(lambda p, d: write_svg(p, d / "x.svg", min_radius_mm=-1), id="min-negative"),
        pytest.param(lambda p, d: write_svg(p, d / "x.svg", min_radius_mm=2, max_radius_mm=1), id="min-above-max"),
        pytest.param(lambda p, d: write_svg(p, d / "x.svg", pen_width_mm=1, max_radius_mm=0.2), id="pen-above-max"),
        pytest.param(lambda p, d: rasterize_dots(PointSet(p.xy, radius=[-0.1]), 10), id="negative-radius"),
        pytest.param(lambda p, d: rasterize_dots(PointSet(p.xy, radius=[math.nan]), 10), id="nan-radius"),
        pytest.param(lambda p, d: rasterize_dots(PointSet([[math.nan, 0.5]]), 10), id="nan-position"),
    ],
)
def test_bad_arguments_raise_patternshop_error(call, tmp_path: Path) -> None:
    with pytest.raises(PatternshopError) as info:
        call(dot(0.5, 0.5, 0.1), tmp_path)
    assert "\n" not in str(info.value)
    assert listing(tmp_path) == []
