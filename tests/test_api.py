"""The Python API (``import patternshop as ps``): the README's examples run, the functions do what they say, the
import stays light, and the CLI gives what the API gives for the same inputs."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import fresh_python_lines, run_cli
from PIL import Image

import patternshop as ps
from synthesis.errors import PatternshopError, PatternshopWarning

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS_PAGE = ROOT / "docs" / "python-api.md"
API_HEADING = "## Python API"
HEAVY_MODULES = ("torch", "onnxruntime", "lightning", "numba")


def python_examples(path: Path, heading: str = API_HEADING) -> list[str]:
    """The ```python blocks of the section ``heading`` of a Markdown file, up to the next heading of its level or higher
    (``###`` subsections belong to it; ``#`` comments inside code blocks are not headings)."""
    lines = path.read_text().splitlines(keepends=True)
    level = len(heading.split(" ", 1)[0])
    starts = [i for i, line in enumerate(lines) if line.rstrip() == heading]
    if not starts:
        raise AssertionError(f"{path.name} has no section {heading!r}")
    blocks: list[str] = []
    block: list[str] | None = None
    fenced = False
    for line in lines[starts[0] + 1:]:
        if line.startswith("```"):
            if fenced and block is not None:
                blocks.append("".join(block))
            fenced, block = not fenced, ([] if not fenced and line.strip() == "```python" else None)
            continue
        if fenced:
            if block is not None:
                block.append(line)
        elif (match := re.match(r"(#+) ", line)) and len(match.group(1)) <= level:
            break
    return blocks


def run_examples(path: Path, heading: str) -> subprocess.CompletedProcess:
    """Run a section's examples in order, as one script, in a fresh interpreter in the repository's root."""
    blocks = python_examples(path, heading)
    assert blocks, f"{path.name}: no ```python examples under {heading!r}"
    script = "\n\n".join(blocks)
    return subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=300)


# --- (a) the documented examples ----------------------------------------------------------------------------
def test_readme_python_api_examples_run():
    result = run_examples(README, API_HEADING)
    assert result.returncode == 0, result.stderr[-3000:]


def test_docs_python_api_examples_run():
    """docs/python-api.md: one example per workflow."""
    assert len(python_examples(DOCS_PAGE, "# Python API")) >= 5
    started = time.time()
    result = run_examples(DOCS_PAGE, "# Python API")
    assert result.returncode == 0, result.stderr[-3000:]
    for name in ("photo.txt", "photo.svg", "logo_edited.tif", "logo_edited.txt", "green_analysis.png"):
        path = ROOT / "out" / "api" / name
        assert path.is_file() and path.stat().st_mtime >= started - 1, name
    assert "50/50 iterations" in result.stdout


def test_examples_helper_reads_one_section(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# T\n```python\nskip()\n```\n## Python API\ntext\n```python\na = 1\n```\n### Sub\n```python\nb = 2\n```\n"
                    "```python\n# a comment\nc = 3\n```\n## Next\n```python\nnot_this()\n```\n")
    assert python_examples(page) == ["a = 1\n", "b = 2\n", "# a comment\nc = 3\n"]
    (tmp_path / "none.md").write_text("# T\n")
    with pytest.raises(AssertionError, match="no section"):
        python_examples(tmp_path / "none.md")


# --- (b) the functions ----------------------------------------------------------------------------------------
def test_import_is_light_and_lazy():
    code = ("import sys, patternshop as ps\n"
            f"heavy = {HEAVY_MODULES!r}\n"
            "loaded = lambda: sorted(m for m in heavy if m in sys.modules)\n"
            "print(loaded()); ps.read_map; ps.PointSet; ps.presets(); ps.uniform_map(4); print(loaded())\n")
    assert fresh_python_lines(code, timeout=60)[:2] == ["[]", "[]"]


def test_every_public_name_resolves():
    assert "synthesize" in ps.__all__ and "read_map" in ps.__all__
    for name in ps.__all__:
        assert getattr(ps, name) is getattr(ps.api, name), name
        assert name in dir(ps)
    assert ps.read_map.__module__ == "synthesis.mapio" and ps.synthesize.__module__ == "patternshop.api"
    with pytest.raises(AttributeError):
        ps.no_such_function  # noqa: B018


def test_map_and_point_round_trips(tmp_path):
    lab_map = ps.uniform_map(6, 4, density=0.25, correlation=(10.0, -20.0))
    assert lab_map.lab.shape == (4, 6, 3) and lab_map.domain == (1.0, 4 / 6)
    np.testing.assert_allclose(lab_map.lab[0, 0], [75.0, 10.0, -20.0])
    for name in ("map.tif", "map.L.png"):
        ps.write_map(lab_map, tmp_path / name)
        np.testing.assert_allclose(ps.read_map(tmp_path / name).lab, lab_map.lab, atol=0.01)
    points = ps.PointSet(np.array([[0.1, 0.2], [0.9, 0.6]]), (1.0, 4 / 6), np.array([0.01, 0.02]))
    for name in ("points.txt", "points.csv", "points.npy"):
        ps.write_points(points, tmp_path / name)
        back = ps.read_points(tmp_path / name, domain=points.domain)
        np.testing.assert_allclose(back.xy, points.xy)
        np.testing.assert_allclose(back.radius, points.radius)
    assert ps.read_points(tmp_path / "points.txt").domain == pytest.approx(points.domain)


def test_presets_and_correlations():
    presets = ps.presets()
    assert {"white", "blue", "green", "step"} <= set(presets)
    assert ps.preset("green") == presets["green"]
    assert ps.correlation_ab("green") == presets["green"]
    assert ps.correlation_ab(" 10, -20 ") == (10.0, -20.0) == ps.correlation_ab((10, -20))
    assert ps.correlation_ab(np.array([1.5, 2.5])) == (1.5, 2.5)
    with pytest.raises(PatternshopError, match="unknown preset 'purple'; presets: white, blue"):
        ps.preset("purple")
    with pytest.raises(PatternshopError, match="'purple' is neither a preset"):
        ps.correlation_ab("purple")
    with pytest.raises(PatternshopError, match=r"in \[-128, 127\]"):
        ps.correlation_ab((0, 300))
    with pytest.raises(PatternshopError, match="two numbers"):
        ps.correlation_ab((1, 2, 3))
    with pytest.raises(PatternshopError, match="density must be"):
        ps.uniform_map(4, density=1.5)
    with pytest.raises(PatternshopError, match="width must be an integer"):
        ps.uniform_map(0)


def test_synthesize_reports_progress_and_is_deterministic():
    canvas = ps.uniform_map(24, density=0.5, correlation="blue")
    calls = []
    result = ps.synthesize(canvas, points=300, iterations=6, seed=4,
                           progress=lambda done, total, xy: calls.append((done, total, xy.shape)))
    assert [done for done, _, _ in calls] == list(range(7))  # 0 (the start), then after each iteration
    assert {total for _, total, _ in calls} == {6} and {shape for _, _, shape in calls} == {(300, 2)}
    assert isinstance(result, ps.SynthesisResult) and len(result.points) == 300 and result.points.radius is None
    assert result.points.domain == canvas.domain and len(result.losses) == 6
    again = ps.synthesize(canvas, points=300, iterations=6, seed=4, dot_sizes=True)
    np.testing.assert_array_equal(again.points.xy, result.points.xy)
    assert again.points.radius is not None and np.all(again.points.radius > 0)


def test_synthesize_reads_a_path_and_counts_points_from_the_ink():
    result = ps.synthesize(ROOT / "examples" / "gradient.tif", points_per_ink=600, iterations=0)
    assert len(result.points) == ps.point_count(ps.read_map(ROOT / "examples" / "gradient.tif"), 600)


@pytest.mark.parametrize("kwargs, message", [
    ({"seed": -1}, "seed must be an integer from 0"),
    ({"points": 1}, "points must be an integer at least 2"),
    ({"points_per_ink": 0}, "points_per_ink must be a finite number > 0"),
    ({"iterations": -2}, "iterations must be an integer at least 0"),
    ({"schedule": "slow"}, "unknown schedule 'slow'"),
    ({"threads": 0}, "threads must be an integer at least 1"),
])
def test_synthesize_errors_are_patternshop_errors(kwargs, message):
    with pytest.raises(PatternshopError, match=message):
        ps.synthesize(ps.uniform_map(8), **kwargs)


def test_bad_inputs_are_patternshop_errors(tmp_path):
    with pytest.raises(PatternshopError, match="white everywhere"):
        ps.synthesize(ps.uniform_map(8, density=0.0))
    with pytest.raises(PatternshopError, match="expected a LabMap or the path of a map file, got int"):
        ps.synthesize(42)
    with pytest.raises(PatternshopError, match="no such file"):
        ps.synthesize(tmp_path / "missing.tif")
    with pytest.raises(PatternshopError, match="expected a PointSet"):
        ps.analyze([[0.1, 0.2]])
    with pytest.raises(PatternshopError, match="no such model file"):
        ps.infer(ps.PointSet(np.full((3, 2), 0.5)), model=tmp_path / "missing.onnx")
    with pytest.raises(PatternshopError, match="degenerate"):
        ps.analyze(ps.PointSet(np.full((50, 2), 0.5)))
    with pytest.raises(PatternshopError, match="not a readable palette"):
        ps.presets(ROOT / "README.md")


def test_set_correlation_takes_presets_and_regions():
    lab_map = ps.uniform_map(10, density=0.4, correlation="blue")
    box = ps.rect_region((10, 10), (0.0, 0.0, 0.45, 1.0))
    edited = ps.set_correlation(lab_map, "step", box)
    np.testing.assert_allclose(edited.ab[0, 0], ps.preset("step"))
    np.testing.assert_allclose(edited.ab[0, -1], ps.preset("blue"))
    np.testing.assert_array_equal(edited.L, lab_map.L)
    ramp = ps.density_gradient(edited, (0.5, 0.0), (0.5, 1.0), (0.0, 1.0))
    assert ramp.density()[0, 0] < 0.1 < 0.9 < ramp.density()[-1, 0]
    assert ps.expand(ramp, (1, 2, 3, 4)).lab.shape == (16, 14, 3) and ps.resize(ramp, 5).width == 5


def test_from_image_tone_and_correlation(tmp_path):
    photo, mask = tmp_path / "photo.png", tmp_path / "mask.png"
    Image.fromarray(np.tile(np.linspace(0, 255, 16).astype(np.uint8), (8, 1))).save(photo)
    Image.fromarray(np.where(np.arange(16) < 8, 0, 255).astype(np.uint8)[None].repeat(8, 0)).save(mask)
    lab_map = ps.from_image(photo, correlation="green")
    assert lab_map.lab.shape == (8, 16, 3) and lab_map.domain == (1.0, 0.5)
    assert lab_map.density()[0, 0] > 0.99 and lab_map.density()[0, -1] < 0.01  # black: full ink; white: paper
    np.testing.assert_allclose(lab_map.ab[0, 0], ps.preset("green"))
    inverted = ps.from_image(photo, invert=True, mask=mask, mask_correlation="10,20")
    assert inverted.density()[0, 0] < 0.01
    np.testing.assert_allclose(inverted.ab[0, 0], ps.preset("blue"))  # the default correlation
    np.testing.assert_allclose(inverted.ab[0, -1], (10.0, 20.0))
    labelled = ps.from_image(photo, labels=mask, label_correlations={"255": "red", 0: (5, 5)})
    np.testing.assert_allclose(labelled.ab[0, -1], ps.preset("red"))
    np.testing.assert_allclose(labelled.ab[0, 0], (5.0, 5.0))
    with pytest.raises(PatternshopError, match="gamma must be"):
        ps.from_image(photo, gamma=0)
    with pytest.raises(PatternshopError, match="needs mask_correlation"):
        ps.from_image(photo, mask=mask)


def test_infer_gives_a_map_on_the_patterns_domain():
    pattern = ps.synthesize(ps.uniform_map(32, 16, density=0.6), points=600, iterations=3).points
    model = ps.load_model()
    inference = ps.infer(pattern, model=model, points_per_ink=2000, width=40, symmetries=1, denoise=False)
    assert isinstance(inference, ps.Inference) and inference.lab_map.lab.shape == (20, 40, 3)
    assert inference.scale.points_per_ink == 2000 and not inference.scale.automatic
    assert inference.lab_map.density().mean() == pytest.approx(0.6, abs=0.1)  # calibrated: 600 points at 2000 per unit area on 1 x 0.5
    assert ps.infer_scale(pattern).points_per_ink == pytest.approx(2000)  # synthesize recorded its scale
    assert ps.infer_scale(ps.PointSet(pattern.xy, pattern.domain)).automatic
    with pytest.raises(PatternshopError, match="width must be"):
        ps.infer(pattern, model=model, width=0)


def test_analyze_warns_outside_the_corpus(monkeypatch):
    import synthesis.analysis

    monkeypatch.setattr(synthesis.analysis, "analyze_points", lambda points, palette, progress=False: {"warning": "far"})
    with pytest.warns(PatternshopWarning, match="far"):
        assert ps.analyze(ps.PointSet(np.array([[0.1, 0.1], [0.5, 0.5]])))["warning"] == "far"


# --- (c) the CLI gives what the API gives ---------------------------------------------------------------------
def test_cli_synthesize_equals_api(tmp_path, capsys):
    source, cli_out, api_out = tmp_path / "map.tif", tmp_path / "cli.txt", tmp_path / "api.txt"
    ps.write_map(ps.set_correlation(ps.uniform_map(20, 14, density=0.5), "green", ps.rect_region((14, 20), (0, 0, 0.5, 1))),
                 source)
    status, _, err = run_cli(["synthesize", str(source), str(cli_out), "--points", "400", "--iterations", "8",
                              "--seed", "5", "--dot-sizes", "--no-progress"], capsys)
    assert status == 0, err
    result = ps.synthesize(ps.read_map(source), points=400, iterations=8, seed=5, dot_sizes=True)
    ps.write_points(result.points, api_out)
    assert cli_out.read_text() == api_out.read_text()


def test_cli_infer_equals_api(tmp_path, capsys):
    points, cli_out, api_out = tmp_path / "points.txt", tmp_path / "cli.tif", tmp_path / "api.tif"
    ps.write_points(ps.synthesize(ps.uniform_map(16, density=0.5), points=500, iterations=2).points, points)
    status, _, err = run_cli(["infer", str(points), str(cli_out), "--width", "32", "--symmetries", "1", "--no-denoise"], capsys)
    assert status == 0, err
    ps.write_map(ps.infer(points, width=32, symmetries=1, denoise=False).lab_map, api_out)
    np.testing.assert_array_equal(ps.read_map(cli_out).lab, ps.read_map(api_out).lab)


def test_cli_edit_from_image_and_palette_equal_api(tmp_path, capsys):
    photo = tmp_path / "photo.png"
    Image.fromarray(np.tile(np.linspace(0, 255, 12).astype(np.uint8), (6, 1))).save(photo)
    status, _, err = run_cli(["from-image", str(photo), str(tmp_path / "cli.tif"), "--preset", "green", "--gamma", "1.5"],
                             capsys)
    assert status == 0, err
    from_api = ps.from_image(photo, correlation="green", gamma=1.5)
    ps.write_map(from_api, tmp_path / "api.tif")
    np.testing.assert_array_equal(ps.read_map(tmp_path / "cli.tif").lab, ps.read_map(tmp_path / "api.tif").lab)

    status, _, err = run_cli(["edit", str(tmp_path / "api.tif"), str(tmp_path / "edited_cli.tif"), "--preset", "step",
                              "--rect", "0", "0", "0.5", "0.5", "--gradient", "0", "0", "0.2", "1", "0", "0.8"], capsys)
    assert status == 0, err
    region = ps.rect_region((6, 12), (0, 0, 0.5, 0.5))
    edited = ps.density_gradient(ps.set_correlation(ps.read_map(tmp_path / "api.tif"), "step", region), (0, 0), (1, 0),
                                 (0.2, 0.8), region=region)
    ps.write_map(edited, tmp_path / "edited_api.tif")
    np.testing.assert_array_equal(ps.read_map(tmp_path / "edited_cli.tif").lab, ps.read_map(tmp_path / "edited_api.tif").lab)

    status, out, err = run_cli(["palette", "--list"], capsys)
    assert status == 0, err
    assert {name: (v["a"], v["b"]) for name, v in json.loads(out).items()} == ps.presets()


def test_warnings_reach_the_caller():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ps.infer(ps.PointSet(np.random.default_rng(0).random((300, 2))), points_per_ink=100, width=16, symmetries=1,
                 calibrate=False)
    assert any(issubclass(w.category, PatternshopWarning) and "more than a fully dark map" in str(w.message) for w in caught)
