"""The ``python -m`` tools (training, data, evaluation) report user errors as the CLI does.

One line "python -m MODULE: error: ..." on stderr and status 2; ``--debug`` raises the error with its traceback.
"""

from __future__ import annotations

import argparse
import importlib

import pytest

from synthesis.errors import PatternshopError, run_module_cli

# module -> arguments that fail on a missing input (paths are relative to the test's temporary folder)
FAILING_RUNS = {
    "patternshop_nn.soup": ["nope_a.ckpt", "nope_b.ckpt", "out.ckpt", "--alpha", "0.5"],
    "patternshop_nn.quantize": ["nope.onnx", "out.onnx", "--pairs", "nope_dir"],
    "patternshop_nn.testset": ["score", "nope_dir", "--out", "out"],
    "patternshop_nn.onnx_import": ["nope.onnx", "out.ckpt"],
    "patternshop_nn.distill": ["nope.ckpt", "out.ckpt", "--pairs", "nope_dir"],
    "patternshop_nn.tune_correlation": ["nope.ckpt", "out.ckpt", "--pairs", "nope_dir"],
    "patternshop_nn.tune_encoder": ["nope.ckpt", "out.ckpt", "--pairs", "nope_dir"],
    "patternshop_nn.evaluate": ["--suite", "heldout", "--model", "nope.onnx", "--out", "out.json"],
    "data_gen.preview": ["nope_dir", "out.png"],
    "data_gen.clean_pairs": ["nope_dir", "destination"],
    "data_gen.palette_table": ["--palette", "nope.npz", "--decoding-only"],
    "data_gen.standins": ["faces", "root", "--count", "0"],
}


@pytest.mark.parametrize("module", sorted(FAILING_RUNS))
def test_a_user_error_is_one_line_and_debug_shows_the_traceback(module, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    main = importlib.import_module(module).main
    assert main(FAILING_RUNS[module]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith(f"python -m {module}: error: ") and captured.err.count("\n") == 1, captured.err
    with pytest.raises((PatternshopError, OSError)):
        main([*FAILING_RUNS[module], "--debug"])
    assert not list(tmp_path.iterdir()), "a failed command wrote something"


def test_run_module_cli_passes_the_status_through_and_lets_bugs_raise(capsys):
    def parser() -> argparse.ArgumentParser:
        made = argparse.ArgumentParser(prog="tool")
        made.add_argument("--status", type=int, default=None)
        return made

    assert run_module_cli(parser(), lambda args: args.status, []) == 0
    assert run_module_cli(parser(), lambda args: args.status, ["--status", "3"]) == 3

    def multi_line_error(args: argparse.Namespace) -> None:
        raise PatternshopError("first\n   second")

    assert run_module_cli(parser(), multi_line_error, []) == 2
    assert capsys.readouterr().err == "tool: error: first second\n"

    def bug(args: argparse.Namespace) -> None:
        raise KeyError("a bug, not the user's error")

    with pytest.raises(KeyError):
        run_module_cli(parser(), bug, [])
