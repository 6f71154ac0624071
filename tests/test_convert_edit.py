"""Batch conversion (`patternshop convert`, export.convert) and map edits (`patternshop edit`, synthesis.edits)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import fresh_python_lines, run_cli
from PIL import Image

from export.convert import FAILED, SKIPPED, WRITTEN, convert_points, map_files, point_files
from synthesis.edits import density_gradient, expand, linear_ramp, read_region, rect_region, resize, set_correlation
from patternshop_nn.onnx_export import export_onnx
from export.runtime import OnnxModel
from patternshop_nn.networks import DualBranchUNet
from synthesis.errors import PatternshopError
from synthesis.labmap import LabMap
from synthesis.mapio import read_map, write_channels, write_tiff
from synthesis.palette import load_palette
from synthesis.points import PointSet, read_points, write_points


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """Run the CLI in-process; returns (exit status, stderr)."""
    status, _, err = run_cli(argv, capsys)
    return status, err


def flat_map(height: int, width: int, L: float = 60.0, ab: tuple[float, float] = (10.0, -20.0)) -> LabMap:
    lab = np.empty((height, width, 3), np.float32)
    lab[...] = (L, *ab)
    return LabMap(lab)


@pytest.fixture(scope="module")
def tiny_onnx(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("model") / "tiny.onnx"
    export_onnx(DualBranchUNet(base_channels=4, max_channels=8), path, {"name": "tiny"})
    return path


@pytest.fixture
def points_dir(tmp_path: Path) -> Path:
    """Three good point files (one non-square, one .npy), two bad ones, and a file that is not a point file."""
    folder = tmp_path / "points"
    folder.mkdir()
    rng = np.random.default_rng(0)
    write_points(PointSet(rng.random((300, 2))), folder / "a.txt")
    write_points(PointSet(rng.random((200, 2)) * [1.0, 0.5], (1.0, 0.5)), folder / "b.txt")
    np.save(folder / "c.npy", rng.random((100, 2)))
    (folder / "bad1.txt").write_text("0.1 0.2\n0.3 zz\n")
    (folder / "bad2.npy").write_bytes(b"not an array")
    (folder / "notes.md").write_text("ignored")
    return folder


def test_convert_continues_past_bad_files(points_dir, tiny_onnx, tmp_path, capsys):
    out = tmp_path / "maps"
    argv = ["convert", str(points_dir), str(out), "--model", str(tiny_onnx), "--batch-size", "2", "--workers", "2", "--no-progress"]
    status, err = run(argv, capsys)
    assert status == 1
    assert sorted(p.name for p in out.iterdir()) == ["a.tif", "b.tif", "c.tif"]
    assert read_map(out / "a.tif").lab.shape == (256, 256, 3) and read_map(out / "b.tif").lab.shape == (128, 256, 3)
    assert "wrote 3 of 5 files" in err and "2 failed" in err
    assert f"{points_dir / 'bad1.txt'}:2: 'zz' is not a number" in err and str(points_dir / "bad2.npy") in err
    assert "Traceback" not in err

    status, err = run(argv, capsys)  # outputs exist: skipped
    assert status == 1 and "wrote 0 of 5 files" in err and "skipped 3" in err
    status, err = run([*argv, "--overwrite", "--workers", "1"], capsys)
    assert status == 1 and "wrote 3 of 5 files" in err


def test_a_convert_worker_imports_no_progress_bar() -> None:
    """A convert worker imports export.convert and export.runtime, not tqdm (with importlib.metadata, 40 ms of each
    worker's start): only the calling process draws the bar."""
    code = "import sys, export.convert, export.runtime\nprint(sorted({'tqdm', 'importlib.metadata'} & set(sys.modules)))"
    assert fresh_python_lines(code)[-1] == "[]"


def test_convert_points_results_in_order(points_dir, tiny_onnx, tmp_path):
    sources = point_files(points_dir)
    assert [p.name for p in sources] == ["a.txt", "b.txt", "bad1.txt", "bad2.npy", "c.npy"]
    (tmp_path / "out").mkdir()
    write_tiff(flat_map(4, 4), tmp_path / "out" / "c.tif")
    results = convert_points(sources, tmp_path / "out", OnnxModel(tiny_onnx), batch_size=8, workers=1)
    assert [r.source for r in results] == sources
    assert [r.status for r in results] == [WRITTEN, WRITTEN, FAILED, FAILED, SKIPPED]
    assert results[0].output == tmp_path / "out" / "a.tif" and results[2].error.startswith(str(sources[2]))
    assert read_map(tmp_path / "out" / "c.tif").width == 4  # skipped, not overwritten
    np.save(points_dir / "a.npy", np.full((10, 2), 0.5))  # a second input for out/a.tif
    again = convert_points([points_dir / "a.txt", points_dir / "a.npy"], tmp_path / "again", OnnxModel(tiny_onnx), workers=1)
    assert [r.status for r in again] == [WRITTEN, FAILED] and "is made from" in again[1].error


def test_convert_with_good_files_only_exits_0(points_dir, tiny_onnx, tmp_path, capsys):
    for bad in ("bad1.txt", "bad2.npy"):
        (points_dir / bad).unlink()
    status, err = run(["convert", str(points_dir), str(tmp_path / "maps"), "--model", str(tiny_onnx), "--workers", "1"], capsys)
    assert status == 0 and "wrote 3 of 3 files" in err


def test_convert_denoises_as_infer_does_unless_told_not_to(tmp_path, capsys):
    import torch

    from export.runtime import infer_map
    from synthesis.generators import generate

    torch.manual_seed(0)  # tiny_onnx's weights depend on the tests run before; denoising's effect on them does too
    tiny_onnx = tmp_path / "tiny.onnx"  # with l_scale: a model without it is never denoised
    export_onnx(DualBranchUNet(base_channels=4, max_channels=8, upsample="nearest", l_scale=True), tiny_onnx, {"name": "tiny"})
    folder = tmp_path / "points"
    folder.mkdir()
    points = PointSet(generate("white", 10_000, seed=1))
    write_points(points, folder / "a.txt")
    base = ["convert", str(folder), "--model", str(tiny_onnx), "--workers", "1"]
    assert run([base[0], base[1], str(tmp_path / "plain"), *base[2:], "--no-denoise"], capsys)[0] == 0
    assert run([base[0], base[1], str(tmp_path / "denoised"), *base[2:]], capsys)[0] == 0
    model = OnnxModel(tiny_onnx)
    written = {folder: read_map(tmp_path / folder / "a.tif").L for folder in ("plain", "denoised")}
    for folder, denoise in (("plain", False), ("denoised", True)):
        np.testing.assert_allclose(written[folder], infer_map(read_points(tmp_path / "points" / "a.txt"), model, symmetries=1,
                                                              denoise=denoise).lab_map.L, atol=0.01)
    assert np.abs(written["denoised"] - written["plain"]).max() > 0.1  # the flag reached the workers


@pytest.mark.parametrize("l_scale", [True, False])
def test_convert_writes_the_bytes_infer_writes(l_scale, tmp_path, capsys):
    """Two worker processes write, file for file, the TIFF that ``infer --symmetries 1`` writes (convert's default):
    the uncertainty path of a model with ``l_scale`` and the plain reading of one without."""
    import torch

    from synthesis.generators import generate

    torch.manual_seed(0)
    model = tmp_path / "tiny.onnx"
    export_onnx(DualBranchUNet(base_channels=4, max_channels=8, upsample="nearest", l_scale=l_scale), model,
                {"points_per_ink": 8000})
    folder = tmp_path / "points"
    folder.mkdir()
    write_points(PointSet(generate("white", 3000, seed=2), points_per_ink=12_000.0), folder / "square.txt")
    write_points(PointSet(generate("step", 1500, seed=3) * [1.0, 0.5], (1.0, 0.5)), folder / "wide.txt")
    status, err = run(["convert", str(folder), str(tmp_path / "maps"), "--model", str(model), "--workers", "2",
                       "--batch-size", "1", "--no-progress"], capsys)
    assert status == 0, err
    for name in ("square", "wide"):
        status, err = run(["infer", str(folder / f"{name}.txt"), str(tmp_path / f"{name}.tif"), "--model", str(model),
                           "--symmetries", "1"], capsys)
        assert status == 0, err
        assert (tmp_path / "maps" / f"{name}.tif").read_bytes() == (tmp_path / f"{name}.tif").read_bytes()


def test_short_runs_go_to_the_workers_in_small_tasks():
    """40 files on 2 workers go one per task (batches of 8 sent 24 to one worker, 16 to the other); long runs keep
    --batch-size; every file once, in order."""
    from export.convert import _chunks

    for files, processes, batch, size in ((40, 2, 8, 1), (100, 2, 8, 3), (10_000, 2, 8, 8), (5, 1, 2, 1), (1000, 4, 3, 3)):
        chunks = _chunks(list(range(files)), batch, processes)
        assert max(map(len, chunks)) == size and [job for chunk in chunks for job in chunk] == list(range(files))


def test_network_map_is_the_plain_decoding():
    """export.runtime.network_map (plane by plane) gives the values of the map decoded whole, then resampled; values
    beyond [0, 1] are clipped as LabMap clips them."""
    from export.runtime import network_map
    from synthesis.labmap import resample_map

    output = np.random.default_rng(0).uniform(-0.05, 1.05, (3, 70, 90)).astype(np.float32)
    for shape in ((32, 41), (70, 90), (140, 180)):
        np.testing.assert_array_equal(network_map(output, shape).lab, resample_map(LabMap.from_network(output), shape).lab)


def test_resynthesize_two_tiny_maps(tmp_path, capsys):
    folder = tmp_path / "maps"
    folder.mkdir()
    write_tiff(flat_map(16, 16, L=40.0), folder / "square.tif")
    write_channels(flat_map(8, 16, L=70.0), folder / "wide.L.png")
    (folder / "broken.tif").write_bytes(b"junk")
    assert [p.name for p in map_files(folder)] == ["broken.tif", "square.tif", "wide.L.png"]
    out = tmp_path / "points"
    status, err = run(["convert", str(folder), str(out), "--resynthesize", "--points", "40", "--iterations", "3",
                       "--workers", "2", "--no-progress"], capsys)
    assert status == 1
    assert "wrote 2 of 3 files" in err and f"{folder / 'broken.tif'}: not a readable TIFF" in err
    square, wide = read_points(out / "square.txt"), read_points(out / "wide.txt")
    assert len(square) == len(wide) == 40
    assert square.domain == (1.0, 1.0) and wide.domain == (1.0, 0.5)


def test_convert_usage_errors(tmp_path, capsys):
    status, err = run(["convert", str(tmp_path / "missing"), str(tmp_path / "out")], capsys)
    assert status == 2 and "no such folder" in err
    status, err = run(["convert", str(tmp_path), str(tmp_path / "out"), "--resynthesize"], capsys)
    assert status == 2 and "no maps" in err


@pytest.mark.parametrize("workers", ["1", "2"])
def test_convert_bad_model_stops_before_any_output(workers, points_dir, tmp_path, capsys):
    """A missing or unreadable model: one line, exit 2, no output folder, with one worker or a pool of them."""
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    for model, message in ((tmp_path / "missing.onnx", "no such model file"), (tmp_path / "junk.onnx", "not a readable ONNX model")):
        status, err = run(["convert", str(points_dir), str(tmp_path / "maps"), "--model", str(model), "--workers", workers,
                           "--batch-size", "1", "--no-progress"], capsys)
        assert status == 2 and message in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "maps").exists()


# --- edits --------------------------------------------------------------------
def test_set_correlation_only_inside_the_rectangle():
    lab_map = flat_map(10, 20)  # domain 1 x 0.5, pixel size 0.05
    region = rect_region((10, 20), (0.2, 0.1, 0.5, 0.3))
    edited = set_correlation(lab_map, (-2.0, -120.0), region)
    inside = region.astype(bool)
    assert inside.sum() == 6 * 4  # centres 0.225..0.475 in x, 0.125..0.275 in y
    np.testing.assert_allclose(edited.ab[inside], [[-2.0, -120.0]] * inside.sum())
    np.testing.assert_array_equal(edited.ab[~inside], lab_map.ab[~inside])
    np.testing.assert_array_equal(edited.L, lab_map.L)
    with pytest.raises(PatternshopError, match="x0 < x1"):
        rect_region((10, 20), (0.5, 0.1, 0.2, 0.3))


def test_set_correlation_with_a_soft_mask(tmp_path):
    mask = np.zeros((6, 8), np.uint8)
    mask[:, 4:] = 255
    mask[:, 3] = 128
    Image.fromarray(mask).save(tmp_path / "mask.png")
    region = read_region(tmp_path / "mask.png", (6, 8))
    edited = set_correlation(flat_map(6, 8, ab=(0.0, 0.0)), (100.0, -100.0), region)
    np.testing.assert_allclose(edited.ab[0, [0, 3, 7]], [[0, 0], [100 * 128 / 255, -100 * 128 / 255], [100, -100]], atol=1e-3)
    with pytest.raises(PatternshopError, match="mask is 8x6 px, the map 9x6 px"):
        read_region(tmp_path / "mask.png", (6, 9))


def test_density_gradient_endpoints():
    lab_map = flat_map(20, 20, L=50.0)
    start, end = (0.025, 0.5), (0.975, 0.5)  # centres of the first and last columns
    edited = density_gradient(lab_map, start, end, (0.2, 0.8))
    density = edited.density()
    np.testing.assert_allclose(density[:, 0], 0.2, atol=1e-5)
    np.testing.assert_allclose(density[:, -1], 0.8, atol=1e-5)
    assert np.all(np.diff(density, axis=1) > 0) and np.ptp(density, axis=0).max() < 1e-5
    scaled = density_gradient(lab_map, start, end, (1.0, 0.0), mode="multiply")
    np.testing.assert_allclose(scaled.density()[:, [0, -1]], [[0.5, 0.0]] * 20, atol=1e-5)
    ramp = linear_ramp((4, 4), (0.5, 0.0), (0.5, 0.5), (0.0, 1.0))  # vertical, constant beyond the end
    np.testing.assert_allclose(ramp[:, 0], [0.25, 0.75, 1.0, 1.0])
    region = rect_region((20, 20), (0.0, 0.0, 1.0, 0.5))
    half = density_gradient(lab_map, start, end, (0.2, 0.8), region=region)
    np.testing.assert_allclose(half.density()[10:], 0.5, atol=1e-5)
    with pytest.raises(PatternshopError, match="densities in"):
        density_gradient(lab_map, start, end, (0.2, 1.5))


def test_expand_and_resize_sizes():
    lab_map = flat_map(10, 20)
    grown = expand(lab_map, (3, 1, 2, 4))
    assert grown.lab.shape == (15, 25, 3)
    np.testing.assert_array_equal(grown.lab, np.broadcast_to(lab_map.lab[0, 0], (15, 25, 3)))
    filled = expand(lab_map, (0, 5, 0, 5), fill=(100.0, 0.0, 0.0))
    assert filled.lab.shape == (20, 20, 3) and filled.domain == (1.0, 1.0)
    np.testing.assert_array_equal(filled.lab[:5], 0 * filled.lab[:5] + [100.0, 0.0, 0.0])
    np.testing.assert_array_equal(filled.lab[5:15], lab_map.lab)
    with pytest.raises(PatternshopError, match="fill"):
        expand(lab_map, (1, 1, 1, 1), fill=(120.0, 0.0, 0.0))
    assert resize(lab_map, 7).lab.shape == (4, 7, 3)


def test_edit_command_fig1_style(tmp_path, capsys):
    source, output = tmp_path / "in.tif", tmp_path / "out.tif"
    write_tiff(flat_map(20, 20, L=50.0, ab=(40.0, 0.0)), source)
    status, err = run(["edit", str(source), str(output), "--rect", "0.25", "0.25", "0.75", "0.75", "--invert",
                       "--preset", "blue", "--gradient", "0", "0", "0.1", "0", "1", "0.5", "--preview", str(tmp_path / "p.png")], capsys)
    assert status == 0, err
    edited, blue = read_map(output), load_palette().preset_ab()["blue"]
    np.testing.assert_allclose(edited.ab[10, 10], [40.0, 0.0], atol=0.01)  # inside the box: kept
    np.testing.assert_allclose(edited.L[10, 10], 50.0, atol=0.01)
    np.testing.assert_allclose(edited.ab[0, 0], blue, atol=0.01)
    assert edited.density()[0, 0] < edited.density()[-1, 0]
    status, err = run(["edit", str(source), str(tmp_path / "big.L.png"), "--expand", "2", "0", "2", "0"], capsys)
    assert status == 0, err
    assert read_map(tmp_path / "big.L.png").lab.shape == (20, 24, 3)


@pytest.mark.parametrize("extra, message", [
    ([], "nothing to do"),
    (["--preset", "nonesuch"], "unknown preset 'nonesuch'"),
    (["--rect", "0", "0", "1", "1"], "select where"),
    (["--ab", "0", "0", "--invert"], "--invert needs"),
    (["--ab", "0", "0", "--region", "missing.png"], "missing.png: no such file"),
])
def test_edit_errors_are_one_line(extra, message, tmp_path, capsys):
    source = tmp_path / "in.tif"
    write_tiff(flat_map(4, 4), source)
    status, err = run(["edit", str(source), str(tmp_path / "out.tif"), *extra], capsys)
    assert status == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out.tif").exists()
