"""The demo loop (examples/demo.py): every output at a tiny size with a tiny untrained model; one-line errors."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from patternshop_nn.onnx_export import export_onnx
from patternshop_nn.module import Pix2PixModule
from synthesis.points import read_points

ROOT = Path(__file__).resolve().parent.parent
DEMO = ROOT / "examples" / "demo.py"


def load_demo():
    spec = importlib.util.spec_from_file_location("patternshop_demo", DEMO)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def tiny_onnx(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "tiny.onnx"
    export_onnx(Pix2PixModule(base_channels=4, max_channels=8), path, {"name": "tiny", "points_per_ink": 8000})
    return path


def test_bundled_points_are_the_logo_at_30000_points_per_ink():
    points = read_points(ROOT / "examples" / "logo_points.txt")
    assert points.domain == pytest.approx((1.0, 2.0 / 3.0))
    assert 5000 < len(points) < 9000  # 30,000 per unit area x the logo's area (2/3) x its mean density (0.36)
    assert points.points_per_ink == pytest.approx(30_000, rel=1e-3)  # its header: infer reads it at that scale
    assert (ROOT / "examples" / "logo_points.txt").stat().st_size < 300_000


def test_demo_writes_every_output(tiny_onnx, tmp_path, capsys):
    demo = load_demo()
    threads = torch.get_num_threads()
    out = tmp_path / "demo"
    size = 48
    status = demo.main(["--model", str(tiny_onnx), "--out", str(out), "--size", str(size), "--png-width", "64",
                        "--iterations", "2", "--points-per-ink", "8000"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    for name in demo.OUTPUTS:
        assert (out / name).stat().st_size > 0, name
    assert not list(out.glob(".*.tmp*"))  # atomic writes leave no temporaries
    summary = json.loads((out / "summary.json").read_text())
    assert summary["input"]["n"] == len(read_points(ROOT / "examples" / "logo_points.txt"))
    assert summary["output"]["n"] == len(read_points(out / "output_points.txt")) > 0
    assert summary["output"]["iterations"] == 2
    assert set(summary["seconds"]) == {"read", "infer", "edit", "synthesize", "write", "total"}
    assert "synth" in captured.out and "contact sheet" in captured.out
    with Image.open(out / "contact_sheet.png") as sheet:
        assert sheet.size == demo.sheet_size(size, (1.0, 2.0 / 3.0))
        assert sheet.width == 4 * size + 5 * demo.GAP  # four panels side by side
        pixels = np.asarray(sheet.convert("L"))
    panel_height = round(size * 2 / 3)
    for slot in range(4):  # every panel holds dots or a map, not the sheet's white
        x = demo.GAP + slot * (size + demo.GAP)
        assert pixels[demo.GAP : demo.GAP + panel_height, x : x + size].min() < 200, slot
    assert torch.get_num_threads() == threads  # the demo restores the caller's torch threads


def test_missing_model_is_one_line_and_exit_2(tmp_path):
    missing = tmp_path / "none.onnx"
    result = subprocess.run([sys.executable, str(DEMO), "--model", str(missing), "--out", str(tmp_path / "o")],
                            capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("demo: error: no model at") and "patternshop export" in lines[0]
    assert not (tmp_path / "o").exists()


def test_bad_option_is_one_line_and_exit_2(capsys):
    demo = load_demo()
    with pytest.raises(SystemExit) as exit_info:
        demo.main(["--size", "abc"])
    assert exit_info.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
