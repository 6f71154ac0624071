"""Distilling the full-resolution path into one on blocks (``python -m patternshop_nn.distill``)."""

from __future__ import annotations

import numpy as np
import onnxruntime
import pytest
import torch

from data_gen.shards import Pairs
from patternshop_nn.distill import DistillSettings, distill_path, main, student_of
from patternshop_nn.module import Pix2PixModule
from patternshop_nn.onnx_export import export_onnx


def teacher(full_res: int = 4) -> Pix2PixModule:
    """A tiny generator whose path (if any) sharpens L by the counts: a correction the block path can learn."""
    torch.manual_seed(0)
    module = Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, upsample="nearest", l_scale=True,
                           full_res_channels=full_res)
    if full_res:
        path = module.generator
        with torch.no_grad():
            for conv in (path.full_res[0], path.full_res[2]):  # channel 0 carries the raster through
                conv.weight.zero_()
                conv.bias.zero_()
                conv.weight[0, 0, 1, 1] = 1.0
            path.refine.weight.zero_()
            path.refine.weight[0, 0] = torch.tensor([[0.0, -1.0, 0.0], [-1.0, 4.0, -1.0], [0.0, -1.0, 0.0]])
    return module.eval()


def rasters(n: int = 24, seed: int = 1) -> torch.Tensor:
    return (torch.rand(n, 1, 64, 64, generator=torch.Generator().manual_seed(seed)) < 0.15).float()


def test_the_student_keeps_every_other_weight_and_learns_the_teachers_l():
    settings = DistillSettings(channels=8, stride=2, steps=300, batch_size=8, lr=3e-3)
    master = teacher()
    student, report = distill_path(master, rasters(), settings)
    # held out, the student's L is much nearer the teacher's than the network without a path
    assert report["held_out_l_error"] < 0.4 * report["held_out_l_error_without_path"]
    assert report["held_out_l_error_without_path"] > 5.0  # the teacher's path matters (L units)
    assert student.generator.full_res_stride == 2 and student.hparams.full_res_stride == 2
    taught = {k: v for k, v in student.state_dict().items() if not k.startswith(("generator.full_res", "generator.refine"))}
    for name, value in taught.items():  # the body and the discriminator: the teacher's, untouched
        torch.testing.assert_close(value, master.state_dict()[name], rtol=0, atol=0)
    x = rasters(2, seed=5)
    with torch.no_grad():
        (lab, scale), (want_lab, want_scale) = student.generator.forward_with_scale(x), master.generator.forward_with_scale(x)
    torch.testing.assert_close(lab[:, 1:], want_lab[:, 1:], rtol=0, atol=0)  # a, b and the scale are the teacher's
    torch.testing.assert_close(scale, want_scale, rtol=0, atol=0)


def test_a_teacher_without_a_path_or_a_bad_stride_is_refused():
    from synthesis.errors import PatternshopError

    with pytest.raises(PatternshopError, match="no full-resolution path"):
        student_of(teacher(0), 8, 4)
    with pytest.raises(ValueError, match="full_res_stride"):
        student_of(teacher(), 8, 3)


def test_the_command_writes_a_checkpoint_that_exports(tmp_path, capsys):
    master = teacher()
    checkpoint = tmp_path / "teacher.ckpt"
    torch.save({"state_dict": master.state_dict(), "hyper_parameters": dict(master.hparams),
                "pytorch-lightning_version": "2"}, checkpoint)
    folder = tmp_path / "pairs"
    folder.mkdir()
    x = rasters(12).numpy()[:, 0].astype(np.float16)
    Pairs(np.arange(12), x, np.zeros((12, 64, 64, 3), np.uint8), np.zeros((0, 2), np.float32),
          np.zeros(13, np.int64), [{} for _ in range(12)]).write(folder / "pairs-00000.npz")
    out = tmp_path / "student.ckpt"
    assert main([str(checkpoint), str(out), "--pairs", str(folder), "--channels", "4", "--stride", "2", "--steps", "5"]) == 0
    assert "held-out |L - teacher's L|" in capsys.readouterr().out
    saved = torch.load(out, weights_only=False)
    assert saved["hyper_parameters"]["full_res_stride"] == 2 and saved["distillation"]["steps"] == 5
    export_onnx(out, tmp_path / "student.onnx", {"points_per_ink": 8000})
    exported = onnxruntime.InferenceSession(str(tmp_path / "student.onnx"), providers=["CPUExecutionProvider"]).run(
        None, {"raster": x[:2, None].astype(np.float32)})[0]
    student = Pix2PixModule.load_from_checkpoint(out, map_location="cpu").generator.eval()
    with torch.no_grad():
        assert np.abs(exported - student(torch.from_numpy(x[:2, None].astype(np.float32))).numpy()).max() < 1e-4
    # a missing teacher: one line, exit 2
    assert main([str(tmp_path / "none.ckpt"), str(out), "--pairs", str(folder)]) == 2
    assert capsys.readouterr().err.count("\n") == 1
