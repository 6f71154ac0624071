"""Issue 15: resource bounds, checks before work, all-or-nothing outputs, Ctrl+C, exit codes, threads, start-up.

Each test names the behaviour it guards; each failed on the code before the issue was worked on.
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import one_line_error, random_map, run_cli
from PIL import Image

from synthesis.atomic import atomic_write_text
from synthesis.labmap import LabMap

ROOT = Path(__file__).resolve().parent.parent
LOGO_MAP = ROOT / "examples" / "logo.tif"



@pytest.fixture
def no_synthesis(monkeypatch: pytest.MonkeyPatch) -> None:
    """Synthesis must not start: a command that runs it fails the test."""
    import synthesis.synthesize

    def refuse(*args, **kwargs):
        raise AssertionError("synthesis ran before the arguments were checked")

    monkeypatch.setattr(synthesis.synthesize, "synthesize", refuse)


# --- 1. resource bounds ---------------------------------------------------------------------------------------
def test_synthesize_of_ten_million_points_is_refused_before_work(small_map, tmp_path, capsys, no_synthesis):
    status, _, err = run_cli(["synthesize", str(small_map), str(tmp_path / "o.txt"), "--points", "10000000"], capsys)
    assert status == 2
    one_line_error(err, "10,000,000 points", "GB", "--max-memory-gb")


def test_synthesize_of_an_8000_px_map_is_refused_before_reading_it(tmp_path, capsys, no_synthesis):
    big = tmp_path / "big.png"
    Image.new("L", (8000, 8000), 128).save(big)
    status, _, err = run_cli(["synthesize", str(big), str(tmp_path / "o.txt")], capsys)
    assert status == 2
    one_line_error(err, "64,000,000-pixel map", "--max-memory-gb")


def test_max_memory_gb_lifts_the_limit(small_map, tmp_path, capsys):
    argv = ["synthesize", str(small_map), str(tmp_path / "o.txt"), "--points", "1000000", "--iterations", "1"]
    status, _, err = run_cli(argv + ["--max-memory-gb", "0.5"], capsys)
    assert status == 2
    one_line_error(err, "over the limit of 0.5 GB")


def test_preview_scale_100000_is_refused(small_map, tmp_path, capsys):
    status, _, err = run_cli(["preview", str(small_map), str(tmp_path / "p.png"), "--scale", "100000"], capsys)
    assert status == 2
    one_line_error(err, "--scale 100000", "--max-memory-gb")
    assert not (tmp_path / "p.png").exists()


def test_edit_expand_by_a_million_pixels_is_refused(tmp_path, capsys):
    status, _, err = run_cli(["edit", str(LOGO_MAP), str(tmp_path / "e.tif"), "--expand", "1000000", "0", "0", "0"], capsys)
    assert status == 2
    one_line_error(err, "1000384x256 px", "--max-memory-gb")
    assert not (tmp_path / "e.tif").exists()


def test_analyze_checks_its_memory(points_file, capsys):
    status, _, err = run_cli(["analyze", str(points_file), "--max-memory-gb", "0.5"], capsys)
    assert status == 2
    one_line_error(err, "500 points", "--max-memory-gb")


def test_infer_width_20000_and_points_per_ink_1e12_are_refused(points_file, tmp_path, capsys):
    model = no_metadata_model(tmp_path, patternshop_format=True)
    for extra, fragment in ((["--width", "20000"], "20000 px wide"), (["--points-per-ink", "1e12"], "1e+12 points per ink")):
        status, _, err = run_cli(["infer", str(points_file), str(tmp_path / "m.tif"), "--model", str(model), *extra], capsys)
        assert status == 2
        one_line_error(err, fragment, "--max-memory-gb")
    assert not (tmp_path / "m.tif").exists()


# --- 2. checks before work, all outputs or none, temporaries, Ctrl+C -------------------------------------------
@pytest.mark.parametrize("extra", [["--png", "{missing}/x.png"], ["--svg", "{missing}/x.svg"], ["--report", "{missing}/r.json"],
                                   ["--png", "{tmp}/x.png", "--png-width", "0"], ["--svg", "{tmp}/x.svg", "--svg-width", "-5"]])
def test_synthesize_checks_every_output_before_work(extra, small_map, tmp_path, capsys, no_synthesis):
    extra = [e.format(missing=tmp_path / "missing", tmp=tmp_path) for e in extra]
    status, _, err = run_cli(["synthesize", str(small_map), str(tmp_path / "o.txt"), *extra], capsys)
    assert status == 2
    one_line_error(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.tif"]


def test_synthesize_into_a_missing_folder_fails_before_work(small_map, tmp_path, capsys, no_synthesis):
    status, _, err = run_cli(["synthesize", str(small_map), str(tmp_path / "nodir" / "o.txt")], capsys)
    assert status == 2
    one_line_error(err, "does not exist")


@pytest.mark.parametrize("command", ["infer", "edit"])
def test_preview_into_a_missing_folder_leaves_no_map(command, small_map, points_file, tmp_path, capsys):
    model = no_metadata_model(tmp_path, patternshop_format=True)
    inputs = [str(points_file), str(tmp_path / "m.tif"), "--model", str(model)] if command == "infer" \
        else [str(small_map), str(tmp_path / "m.tif"), "--preset", "blue"]
    status, _, err = run_cli([command, *inputs, "--preview", str(tmp_path / "nodir" / "p.png")], capsys)
    assert status == 2
    one_line_error(err, "does not exist")
    assert not (tmp_path / "m.tif").exists()


def test_synthesize_replaces_all_its_outputs_or_none(small_map, tmp_path, capsys, monkeypatch):
    import synthesis.render

    outputs = {name: tmp_path / name for name in ("o.txt", "o.png", "o.svg", "o.json")}
    for path in outputs.values():
        path.write_text("old")

    def disk_full(*args, **kwargs):
        raise OSError("No space left on device")

    monkeypatch.setattr(synthesis.render, "write_svg", disk_full)
    status, _, err = run_cli(["synthesize", str(small_map), str(outputs["o.txt"]), "--png", str(outputs["o.png"]),
                              "--svg", str(outputs["o.svg"]), "--report", str(outputs["o.json"]), "--points", "40",
                              "--iterations", "2", "--no-progress"], capsys)
    assert status == 2
    one_line_error(err, "No space left")
    assert all(path.read_text() == "old" for path in outputs.values())
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*outputs, "small.tif"])  # no temporaries


def test_all_or_nothing_renames_at_the_end_only(tmp_path):
    from synthesis.atomic import all_or_nothing

    first, second = tmp_path / "a.txt", tmp_path / "b.txt"
    with pytest.raises(RuntimeError), all_or_nothing():
        atomic_write_text(first, "new")
        assert not first.exists()  # written to a temporary, renamed at the end of the block
        raise RuntimeError
    assert list(tmp_path.iterdir()) == []
    with all_or_nothing():
        atomic_write_text(first, "1")
        atomic_write_text(second, "2")
    assert first.read_text() + second.read_text() == "12"


def test_stale_temporaries_of_dead_processes_are_removed(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f".o.txt.{int(dead.stdout)}.abc123.tmp.txt"  # left by a run killed with kill -9
    stale.write_text("")
    alive = tmp_path / f".o.txt.{os.getpid()}.def456.tmp.txt"  # a running process's: kept
    alive.write_text("")
    atomic_write_text(tmp_path / "o.txt", "points")
    assert not stale.exists() and alive.exists()


def test_ctrl_c_stops_convert_resynthesize_with_two_workers(tmp_path):
    maps, out = tmp_path / "maps", tmp_path / "out"
    maps.mkdir()
    for i in range(6):
        (maps / f"m{i}.tif").write_bytes(LOGO_MAP.read_bytes())
    # a terminal's Ctrl+C reaches a program that handles SIGINT; a test runner started in the background ignores
    # SIGINT, and the child would inherit that (Python then installs no KeyboardInterrupt handler)
    process = subprocess.Popen([sys.executable, "-m", "patternshop", "convert", str(maps), str(out), "--resynthesize",
                                "--workers", "2", "--points", "20000", "--no-progress"],
                               stderr=subprocess.PIPE, text=True, start_new_session=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        time.sleep(5.0)  # workers started (about 1 s each) and synthesising (about 10 s per map)
        before = {p.name for p in out.glob("*.txt")}
        os.killpg(process.pid, signal.SIGINT)
        interrupted = time.monotonic()
        _, err = process.communicate(timeout=10)
        assert time.monotonic() - interrupted < 2.0
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == 130, err
    assert err.strip().splitlines() == ["patternshop convert: interrupted"]
    assert {p.name for p in out.iterdir()} == before  # nothing new, no temporaries
    deadline = time.monotonic() + 2.0
    while _group_alive(process.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _group_alive(process.pid)  # no worker left behind


def _group_alive(group: int) -> bool:
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return False
    return True


# --- 3. exit codes and messages ---------------------------------------------------------------------------------
@pytest.mark.parametrize("option", [["--seed", "-1"], ["--seed", "1e23"], ["--seed", "100000000000000000000000"], ["--seed", "4294967296"],
                                    ["--points-per-ink", "nan"], ["--points-per-ink", "-3"], ["--points", "0"],
                                    ["--iterations", "0"], ["--threads", "0"], ["--max-memory-gb", "inf"]])
def test_bad_numbers_are_usage_errors(option, small_map, tmp_path, capsys, no_synthesis):
    status, _, err = run_cli(["synthesize", str(small_map), str(tmp_path / "o.txt"), *option], capsys)
    assert status == 2
    one_line_error(err, option[0])


def test_tiff_cut_inside_its_header_is_one_line(tmp_path):
    cut = tmp_path / "cut.tif"
    cut.write_bytes(LOGO_MAP.read_bytes()[:200])
    # in a subprocess: pytest's log capture would hide tifffile's log lines from stderr
    result = subprocess.run([sys.executable, "-m", "patternshop", "preview", str(cut), str(tmp_path / "p.png")],
                            capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    one_line_error(result.stderr, "not a readable TIFF")


def test_text_file_named_npy_and_garbage_palette_say_what_they_are(small_map, tmp_path, capsys, no_synthesis):
    text = tmp_path / "points.npy"
    text.write_text("0.1 0.2\n0.3 0.4\n")
    status, _, err = run_cli(["points", str(text)], capsys)
    assert status == 2
    assert "pickle" not in one_line_error(err, "not a readable .npy file")
    status, _, err = run_cli(["synthesize", str(small_map), str(tmp_path / "o.txt"), "--palette", str(text)], capsys)
    assert status == 2
    assert "pickle" not in one_line_error(err, "not a palette")


def test_garbage_checkpoint_gives_no_torch_advice(tmp_path, capsys):
    checkpoint = tmp_path / "model.ckpt"
    checkpoint.write_bytes(pickle.dumps({"state_dict": "not weights"}))
    status, _, err = run_cli(["export", str(checkpoint), str(tmp_path / "m.onnx")], capsys)
    assert status == 2
    assert "weights_only" not in one_line_error(err, "not a Pix2PixModule checkpoint")


def no_metadata_model(tmp_path: Path, patternshop_format: bool = False) -> Path:
    """A 3-channel ONNX model with the right input and output names (map = the raster three times)."""
    import onnx
    from onnx import TensorProto, helper

    raster = helper.make_tensor_value_info("raster", TensorProto.FLOAT, ["B", 1, "H", "W"])
    output = helper.make_tensor_value_info("map", TensorProto.FLOAT, ["B", 3, "H", "W"])
    graph = helper.make_graph([helper.make_node("Concat", ["raster"] * 3, ["map"], axis=1)], "unrelated", [raster], [output])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    if patternshop_format:
        helper.set_model_props(model, {"patternshop_format": "1", "raster_size": "256", "points_per_ink": "8000"})
    path = tmp_path / ("ours.onnx" if patternshop_format else "unrelated.onnx")
    onnx.save(model, path)
    return path


def test_unrelated_onnx_model_is_refused(points_file, tmp_path, capsys):
    status, _, err = run_cli(["infer", str(points_file), str(tmp_path / "m.tif"), "--model", str(no_metadata_model(tmp_path))],
                             capsys)
    assert status == 2
    one_line_error(err, "not a Patternshop model")
    assert not (tmp_path / "m.tif").exists()


def test_edit_that_selects_no_pixel_is_refused(small_map, tmp_path, capsys):
    status, _, err = run_cli(["edit", str(small_map), str(tmp_path / "e.tif"), "--rect", "2", "2", "3", "3", "--preset", "blue"],
                             capsys)
    assert status == 2
    one_line_error(err, "selects no pixel")
    black = tmp_path / "black.png"
    Image.new("L", (32, 24), 0).save(black)
    status, _, err = run_cli(["edit", str(small_map), str(tmp_path / "e.tif"), "--region", str(black), "--ab", "10", "10"],
                             capsys)
    assert status == 2
    one_line_error(err, "selects no pixel")
    assert not (tmp_path / "e.tif").exists()


# --- 4. threads -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("command", ["synthesize", "analyze", "infer", "convert", "palette", "export"])
def test_compute_commands_take_threads_default_1(command, capsys):
    from patternshop.cli import build_parser

    positional = {"synthesize": ["m.tif", "o.txt"], "analyze": ["p.txt"], "infer": ["p.txt", "m.tif"],
                  "convert": ["in", "out"], "palette": ["p.png"], "export": ["c.ckpt", "m.onnx"]}[command]
    parser = build_parser()
    assert parser.parse_args([command, *positional]).threads == 1
    assert parser.parse_args([command, *positional, "--threads", "2"]).threads == 2


def test_thread_limit_sets_and_restores():
    from patternshop.commands import thread_limit

    before = os.environ.get("OMP_NUM_THREADS")
    with thread_limit(3):
        assert os.environ["OMP_NUM_THREADS"] == os.environ["NUMBA_NUM_THREADS"] == "3"
    assert os.environ.get("OMP_NUM_THREADS") == before


def test_tests_run_single_threaded():
    assert os.environ["OMP_NUM_THREADS"] == "1" and os.environ["NUMBA_NUM_THREADS"] == "1"


# --- 5. start-up and imports ------------------------------------------------------------------------------------
HEAVY = ("numpy", "colour", "torch", "matplotlib", "pandas", "onnxruntime", "scipy")


def imported_after(code: str) -> list[str]:
    """The heavy top-level packages loaded by ``code`` in a fresh interpreter."""
    probe = f"{code}\nimport sys\nprint(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, cwd=ROOT)
    return [m for m in result.stdout.strip().split(",") if m]


def test_help_imports_nothing_heavy_and_version_is_fast():
    assert imported_after("from patternshop import cli; cli.build_parser().format_help()") == []
    fastest = min(_seconds([sys.executable, "-m", "patternshop", "--version"]) for _ in range(5))
    assert fastest <= 0.3


def _seconds(argv: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(argv, capture_output=True, check=True, cwd=ROOT)
    return time.perf_counter() - start


def test_preview_imports_neither_colour_nor_torch(tmp_path):
    loaded = imported_after(f"from patternshop import cli; cli.main(['preview', {str(LOGO_MAP)!r}, {str(tmp_path / 'p.png')!r}])")
    assert not {"colour", "torch", "matplotlib", "pandas"} & set(loaded)


def test_lab_conversions_match_colour_science():
    colour = pytest.importorskip("colour")
    d65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    rng = np.random.default_rng(0)
    rgb = rng.random((64, 64, 3))
    rgb[:8] *= 0.03  # the linear segment of the sRGB curve
    expected = colour.XYZ_to_Lab(colour.RGB_to_XYZ(rgb, "sRGB", apply_cctf_decoding=True), d65)
    np.testing.assert_allclose(LabMap.from_srgb(rgb).lab, expected, atol=1e-4)  # float32 storage
    lab = random_map(64, 64, seed=1).lab.astype(np.float64)
    expected = np.clip(colour.XYZ_to_RGB(colour.Lab_to_XYZ(lab, d65), "sRGB", apply_cctf_encoding=True), 0, 1)
    np.testing.assert_allclose(LabMap(lab).to_srgb(), expected, atol=1e-6)
