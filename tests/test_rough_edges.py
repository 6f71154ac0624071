"""Issue 26, item 5: rough edges a hostile tester found, one test each.

Unwritable outputs found before work, progress and Ctrl+C in ``analyze``, degenerate patterns in ``infer``,
folders given as files, plain numbers in messages, file names in decoding errors, frames/pages/channels that
are not read, ``--preview-every`` after ``kill -9``, and the first run's kernel compilation.
"""

from __future__ import annotations

import fcntl
import os
import pty
import select
import signal
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile
from helpers import one_line_error, random_map, run_cli
from PIL import Image

from synthesis.errors import PatternshopError, PatternshopWarning
from synthesis.mapio import read_map
from synthesis.points import PointSet, read_points, write_points

ROOT = Path(__file__).resolve().parent.parent
LOGO_MAP = ROOT / "examples" / "logo.tif"
PATTERNSHOP = [sys.executable, "-m", "patternshop"]



def _takes_files(folder: Path) -> bool:
    try:
        (folder / ".probe").touch()
    except OSError:
        return False
    (folder / ".probe").unlink()
    return True


@pytest.fixture
def unwritable_folder(tmp_path: Path) -> Path:
    """A folder that takes no new file: read-only by its mode, or (for root, whom modes do not stop) /sys."""
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o555)
    yield folder if not _takes_files(folder) else Path("/sys")
    folder.chmod(0o755)


def _no_work(monkeypatch: pytest.MonkeyPatch) -> None:
    import synthesis.mapio
    import synthesis.synthesize

    def refuse(*args, **kwargs):
        raise AssertionError("the work started before the outputs were checked")

    monkeypatch.setattr(synthesis.synthesize, "synthesize", refuse)
    monkeypatch.setattr(synthesis.mapio, "read_map", refuse)


# --- 1. unwritable outputs ------------------------------------------------------------------------------------
@pytest.mark.parametrize("command", [
    ["synthesize", "{map}", "{out}/o.txt"],
    ["synthesize", "{map}", "{tmp}/o.txt", "--png", "{out}/o.png"],
    ["infer", "{points}", "{out}/m.tif"],
    ["edit", "{map}", "{out}/m.tif", "--ab", "10", "10"],
    ["from-image", "{photo}", "{out}/m.tif"],
])
def test_unwritable_output_folder_is_refused_before_work_naming_the_output(
        command, unwritable_folder, small_map, points_file, tmp_path, capsys, monkeypatch):
    photo = tmp_path / "photo.png"
    Image.fromarray(np.zeros((8, 8), np.uint8)).save(photo)
    _no_work(monkeypatch)
    argv = [a.format(map=small_map, points=points_file, photo=photo, out=unwritable_folder, tmp=tmp_path) for a in command]
    status, _, err = run_cli(argv, capsys)
    assert status == 2
    line = one_line_error(err)
    target = next(a for a in argv if a.startswith(str(unwritable_folder)))
    assert f"{target}: cannot write into folder {unwritable_folder}" in line and ".tmp" not in line, line


def test_a_failed_atomic_write_names_the_target_not_its_temporary(unwritable_folder):
    from synthesis.atomic import atomic_write_text

    with pytest.raises(PatternshopError) as info:
        atomic_write_text(unwritable_folder / "report.json", "{}")
    assert str(info.value).startswith(f"{unwritable_folder / 'report.json'}: cannot write") and ".tmp" not in str(info.value)


# --- 2. analyze: progress and Ctrl+C --------------------------------------------------------------------------
def test_analyze_shows_progress_through_its_stages(capsys):
    from synthesis.analysis import analyze_points
    from synthesis.palette import load_palette

    points = PointSet(np.random.default_rng(0).random((60_000, 2)))
    analyze_points(points, load_palette(), progress=True)
    err = capsys.readouterr().err
    for stage in ("coincident points", "pair correlation", "spectrum", "palette colour"):
        assert f"analyze: {stage}" in err, err[-500:]


def test_ctrl_c_stops_analyze_of_a_million_points_within_two_seconds(tmp_path):
    path = tmp_path / "big.npy"
    np.save(path, np.random.default_rng(0).random((1_000_000, 2)))
    primary, secondary = pty.openpty()  # stderr a terminal: the progress bar shows which stage is running
    fcntl.ioctl(secondary, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # tqdm draws nothing on a 0x0 one
    # a test runner in the background ignores SIGINT, and the child would inherit that (see test_robustness)
    process = subprocess.Popen([*PATTERNSHOP, "analyze", str(path)], stdout=subprocess.DEVNULL, stderr=secondary,
                               cwd=ROOT, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    os.close(secondary)
    seen, deadline = b"", time.monotonic() + 60
    try:
        while b"pair correlation" not in seen and time.monotonic() < deadline and process.poll() is None:
            if select.select([primary], [], [], 0.2)[0]:
                seen += os.read(primary, 4096)
        assert b"pair correlation" in seen, seen[-300:]
        process.send_signal(signal.SIGINT)
        interrupted = time.monotonic()
        process.wait(timeout=10)
        assert time.monotonic() - interrupted < 2.0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        while select.select([primary], [], [], 0)[0]:
            try:
                chunk = os.read(primary, 4096)
            except OSError:
                break
            if not chunk:
                break
            seen += chunk
        os.close(primary)
    assert process.returncode == 130
    assert b"patternshop analyze: interrupted" in seen


# --- 3. degenerate patterns: infer refuses them as analyze does -------------------------------------------------
def test_infer_refuses_a_degenerate_pattern_with_analyzes_message(tmp_path, capsys):
    path = tmp_path / "same.txt"
    write_points(PointSet(np.full((10_000, 2), 0.5)), path)
    messages = []
    for argv in (["analyze", str(path)], ["infer", str(path), str(tmp_path / "m.tif")]):
        status, _, err = run_cli(argv, capsys)
        assert status == 2
        messages.append(one_line_error(err).split(": error: ", 1)[1])
    assert messages[0] == messages[1] and "degenerate" in messages[0]
    assert not (tmp_path / "m.tif").exists()


def test_a_pattern_filling_a_small_part_of_its_domain_is_not_degenerate():
    from synthesis.analysis import check_not_degenerate

    rng = np.random.default_rng(0)
    check_not_degenerate(PointSet(0.45 + 0.1 * rng.random((20_000, 2))))  # Poisson on 1 % of the canvas: judged at its spacing
    with pytest.raises(PatternshopError, match="of 10000 points lie on top of another point"):
        check_not_degenerate(PointSet(np.concatenate([np.full((6000, 2), 0.5), rng.random((4000, 2))])))


# --- 4. a folder where a file belongs ---------------------------------------------------------------------------
@pytest.mark.parametrize("command, what", [
    (["from-image", "{dir}", "{tmp}/m.tif"], "an image file"),
    (["from-image", "{photo}", "{tmp}/m.tif", "--mask", "{dir}", "--mask-preset", "red"], "a mask file"),
    (["preview", "{dir}", "{tmp}/p.png"], "a map file"),
    (["points", "{dir}"], "a point file"),
    (["infer", "{points}", "{tmp}/m.tif", "--model", "{dir}"], "an ONNX model file"),
    (["edit", "{map}", "{tmp}/m.tif", "--region", "{dir}", "--ab", "1", "1"], "a mask image file"),
])
def test_a_folder_given_as_a_file_is_named_a_folder(command, what, small_map, points_file, tmp_path, capsys):
    folder = tmp_path / "folder"
    folder.mkdir()
    photo = tmp_path / "photo.png"
    Image.fromarray(np.zeros((8, 8), np.uint8)).save(photo)
    argv = [a.format(dir=folder, tmp=tmp_path, photo=photo, points=points_file, map=small_map) for a in command]
    status, _, err = run_cli(argv, capsys)
    assert status == 2
    assert f"{folder}: is a folder, not {what}" in one_line_error(err)


# --- 5. plain numbers ---------------------------------------------------------------------------------------------
def test_out_of_range_ab_is_reported_with_plain_numbers_and_the_range(small_map, tmp_path, capsys):
    from synthesis.edits import expand, set_correlation

    status, _, err = run_cli(["edit", str(small_map), str(tmp_path / "m.tif"), "--ab", "500", "-900"], capsys)
    assert status == 2
    line = one_line_error(err)
    assert "[-128, 127]" in line and "500, -900" in line and "np." not in line
    lab_map = random_map(4, 4)
    for call in (lambda: set_correlation(lab_map, (np.float64(500), np.float64(-900))),
                 lambda: expand(lab_map, (1, 1, 1, 1), (np.float64(200), np.float64(0), np.float64(0)))):
        with pytest.raises(PatternshopError) as info:
            call()
        assert "np." not in str(info.value) and ("500, -900" in str(info.value) or "200, 0, 0" in str(info.value))


# --- 6. truncated images name their file ----------------------------------------------------------------------
@pytest.mark.parametrize("command", [["preview", "{cut}", "{tmp}/p.png"], ["from-image", "{cut}", "{tmp}/m.tif"]])
def test_a_truncated_png_is_named_in_the_error(command, tmp_path, capsys):
    whole, cut = tmp_path / "whole.png", tmp_path / "cut.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (64, 96, 3), dtype=np.uint8)).save(whole)
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    status, _, err = run_cli([a.format(cut=cut, tmp=tmp_path) for a in command], capsys)
    assert status == 2
    line = one_line_error(err)
    assert f"{cut}: not a readable" in line and "truncated" in line, line


# --- 7. frames, pages and channels that are not read ----------------------------------------------------------
def test_frames_pages_and_extra_channels_that_are_not_read_are_warned_about(tmp_path):
    from synthesis.photo import photo_to_map

    rng = np.random.default_rng(0)
    frames = [Image.fromarray(rng.integers(0, 255, (20, 30), dtype=np.uint8)) for _ in range(3)]
    frames[0].save(tmp_path / "anim.gif", save_all=True, append_images=frames[1:])
    with pytest.warns(PatternshopWarning, match="3 frames or pages; only the first is read"):
        photo_to_map(tmp_path / "anim.gif", (0.0, 0.0))
    lab = rng.integers(0, 255, (20, 30, 4), dtype=np.uint8)
    tifffile.imwrite(tmp_path / "pages.tif", np.stack([lab[..., :3]] * 2), photometric=8)
    with pytest.warns(PatternshopWarning, match="has 2 pages; only the first is read"):
        read_map(tmp_path / "pages.tif")
    tifffile.imwrite(tmp_path / "alpha.tif", lab, photometric=8, extrasamples=[2])
    with pytest.warns(PatternshopWarning, match="4 samples per pixel: only L, a, b are read"):
        assert read_map(tmp_path / "alpha.tif").lab.shape == (20, 30, 3)
    tifffile.imwrite(tmp_path / "rgba.tif", lab, photometric="rgb", extrasamples=[2])
    with pytest.warns(PatternshopWarning) as caught:  # "sRGB image converted" too
        read_map(tmp_path / "rgba.tif")
    assert any("alpha channel is ignored" in str(warning.message) for warning in caught)


# --- 8. --preview-every and kill -9 ------------------------------------------------------------------------------
def test_kill_9_during_preview_every_leaves_a_complete_preview_that_the_next_run_clears(tmp_path):
    output, preview = tmp_path / "points.txt", tmp_path / "points.preview.txt"
    process = subprocess.Popen([*PATTERNSHOP, "synthesize", str(LOGO_MAP), str(output), "--points", "3000",
                                "--iterations", "400", "--preview-every", "1", "--no-progress"],
                               stderr=subprocess.DEVNULL, cwd=ROOT)
    try:
        deadline = time.monotonic() + 90  # a cold kernel cache compiles first
        while not preview.exists() and time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.05)
        time.sleep(0.3)  # several previews written
        assert process.poll() is None and preview.exists()
    finally:
        process.kill()
        process.wait()
    assert len(read_points(preview)) == 3000  # atomic: a whole point file, never a partial one
    assert not output.exists()
    result = subprocess.run([*PATTERNSHOP, "synthesize", str(LOGO_MAP), str(output), "--points", "100",
                             "--iterations", "1", "--preview-every", "1", "--no-progress"],
                            capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["points.txt"]  # no preview, no temporary left


# --- 9. the first run's compilation is announced -----------------------------------------------------------------
def test_a_cold_kernel_cache_is_announced_before_compiling(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    process = subprocess.Popen([*PATTERNSHOP, "synthesize", str(LOGO_MAP), str(tmp_path / "o.txt"), "--points", "300",
                                "--iterations", "1", "--no-progress"], stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)
    try:
        first_line = process.stderr.readline()  # printed before compiling: the process is killed then, not waited for
    finally:
        process.kill()
        process.wait()
    assert first_line.startswith("compiling synthesis kernels (first run only"), first_line
