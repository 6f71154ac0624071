"""The `patternshop` command line: help, exit codes, one-line errors, atomic outputs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli as run
from PIL import Image

from patternshop import cli
from synthesis.mapio import read_map

MALFORMED_POINT_FILES = {
    "columns": ("0.1 0.2 0.3 0.4\n", ":1: expected 2 or 3 columns"),
    "mixed-columns": ("0.1 0.2\n0.3 0.4 0.01\n", ":2: expected 2 columns"),
    "not-a-number": ("0.1 0.2\n0.3 zero\n", ":2: 'zero' is not a number"),
    "nan": ("# a comment\n0.1 nan\n", ":2: non-finite"),
    "inf": ("0.1 0.2\n\ninf 0.2\n", ":3: non-finite"),
    "outside": ("0.1 0.2\n1.5 0.2\n", ":2: point (1.5, 0.2) lies outside the domain"),
    "empty": ("# nothing here\n", "no points (empty file)"),
}


def test_help_lists_commands(capsys):
    status, out, _ = run(["--help"], capsys)
    assert status == 0
    for command in ("preview", "split", "join", "points"):
        assert command in out


def test_version(capsys):
    status, out, _ = run(["--version"], capsys)
    assert status == 0 and out.startswith("patternshop ")


@pytest.mark.parametrize("argv", [[], ["preview"], ["preview", "a.tif", "b.png", "--scale", "x"], ["nonsense"]])
def test_usage_errors_are_one_line_exit_2(argv, capsys):
    status, _, err = run(argv, capsys)
    assert status == 2
    if argv:
        assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("case", sorted(MALFORMED_POINT_FILES))
def test_malformed_points_exit_2_one_line_no_output(case, tmp_path, capsys):
    content, expected = MALFORMED_POINT_FILES[case]
    source, output = tmp_path / "in.txt", tmp_path / "out.npy"
    source.write_text(content)
    status, _, err = run(["points", str(source), str(output)], capsys)
    assert status == 2
    assert len(err.strip().splitlines()) == 1
    assert "Traceback" not in err
    assert str(source) in err and expected in err
    assert not output.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.txt"]


def test_malformed_points_through_console_script(tmp_path):
    """The installed entry point itself: exit 2, one line, no traceback, nothing written."""
    source, output = tmp_path / "in.csv", tmp_path / "out.txt"
    source.write_text("x,y\n0.5,0.5\n0.5,oops\n")
    result = subprocess.run(
        [sys.executable, "-m", "patternshop", "points", str(source), str(output)], capture_output=True, text=True
    )
    assert result.returncode == 2
    assert result.stderr.strip() == f"patternshop points: error: {source}:3: 'oops' is not a number"
    assert not output.exists()


def test_points_conversion_round_trip(tmp_path, capsys):
    xy = np.random.default_rng(1).uniform(0, 1, (50, 2)) * [1.0, 0.5]
    source = tmp_path / "in.npy"
    np.save(source, xy)
    assert run(["points", str(source), str(tmp_path / "p.txt"), "--domain", "1", "0.5"], capsys)[0] == 0
    status, out, _ = run(["points", str(tmp_path / "p.txt"), str(tmp_path / "p.csv")], capsys)
    assert status == 0 and "50 points in [0, 1] x [0, 0.5]" in out
    back = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(back, xy, rtol=1e-8)


def test_points_domain_is_checked(tmp_path, capsys):
    source = tmp_path / "in.txt"
    source.write_text("0.2 0.7\n")
    status, _, err = run(["points", str(source), "--domain", "1", "0.5"], capsys)
    assert status == 2 and "outside the domain [0, 1] x [0, 0.5]" in err


def test_preview_split_join(map_tif, tmp_path, capsys):
    preview = tmp_path / "p.png"
    assert run(["preview", str(map_tif), str(preview), "--scale", "3"], capsys)[0] == 0
    with Image.open(preview) as image:
        assert image.mode == "RGB" and image.size == (18 * 3, 12 * 3)

    assert run(["split", str(map_tif), str(tmp_path / "ch")], capsys)[0] == 0
    assert all((tmp_path / f"ch.{c}.png").exists() for c in "Lab")
    joined = tmp_path / "joined.tif"
    assert run(["join", str(tmp_path / "ch.b.png"), str(joined)], capsys)[0] == 0
    np.testing.assert_allclose(read_map(joined).lab, read_map(map_tif).lab, atol=0.01)

    joined8 = tmp_path / "joined8.tif"
    assert run(["join", str(tmp_path / "ch"), str(joined8), "--bits", "8"], capsys)[0] == 0
    np.testing.assert_allclose(read_map(joined8).lab, read_map(map_tif).lab, atol=0.5 + 1e-3)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["preview", "{map}", "{tmp}/p.jpg"], "output must end in .png"),
        (["join", "{tmp}/none.L.png", "{tmp}/j.tif"], "no such file"),
        (["join", "{map}", "{tmp}/j.png"], "output must end in .tif or .tiff"),
        (["preview", "{tmp}/missing.tif", "{tmp}/p.png"], "missing.tif: no such file"),
        (["preview", "{map}", "{tmp}/no/such/dir/p.png"], "does not exist"),
        (["split", "{map}", "{tmp}/map.tif"], "give NAME"),
        (["split", "{tmp}/m.L.png", "{tmp}/m.png"], "overwrite the input"),
    ],
)
def test_map_command_errors(argv, message, map_tif, tmp_path, capsys):
    before = sorted(tmp_path.rglob("*"))
    status, _, err = run([a.format(map=map_tif, tmp=tmp_path) for a in argv], capsys)
    assert status == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert message in err
    assert sorted(tmp_path.rglob("*")) == before


def test_preview_refuses_to_overwrite_its_input(tmp_path, capsys):
    source = tmp_path / "m.png"
    Image.new("RGB", (4, 4), (120, 50, 200)).save(source)
    before = source.read_bytes()
    status, _, err = run(["preview", str(source), str(source)], capsys)
    assert status == 2 and "overwrite the input" in err
    assert source.read_bytes() == before


def test_srgb_input_warns_on_one_line(tmp_path, capsys):
    source = tmp_path / "m.png"
    Image.new("RGB", (4, 4), (120, 50, 200)).save(source)
    status, _, err = run(["preview", str(source), str(tmp_path / "p.png")], capsys)
    assert status == 0
    warning_lines = [line for line in err.splitlines() if line.startswith("patternshop: warning:")]
    assert len(warning_lines) == 1 and "converted to CIELAB" in warning_lines[0]


def test_internal_errors_one_line_unless_debug(map_tif, tmp_path, capsys, monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("boom\nsecond line")

    monkeypatch.setattr("synthesis.mapio.write_preview", broken)
    argv = ["preview", str(map_tif), str(tmp_path / "p.png")]
    status, _, err = run(argv, capsys)
    assert status == 1
    assert err.strip().splitlines() == [
        "patternshop preview: internal error: RuntimeError: boom second line (rerun with --debug for the traceback)"
    ]
    with pytest.raises(RuntimeError, match="boom"):
        cli.main(["--debug", *argv])
    with pytest.raises(RuntimeError, match="boom"):
        cli.main([*argv, "--debug"])


def test_interrupted_write_leaves_nothing(map_tif, tmp_path, capsys, monkeypatch):
    """A failure halfway through writing (disk full, Ctrl-C) leaves no partial output."""
    target = tmp_path / "p.png"

    def half_write(self, fp, *args, **kwargs):
        Path(fp).write_bytes(b"\x89PNG partial")
        raise OSError("No space left on device")

    monkeypatch.setattr(Image.Image, "save", half_write)
    status, _, err = run(["preview", str(map_tif), str(target)], capsys)
    assert status == 2 and "No space left on device" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.tif"]
