"""patternshop_nn.graft: L and its scale from one checkpoint, a, b from another's own correlation branch."""

from __future__ import annotations

import numpy as np
import torch

from patternshop_nn.graft import main
from patternshop_nn.module import Pix2PixModule, save_module_checkpoint
from patternshop_nn.onnx_export import load_module

TINY = dict(base_channels=4, max_channels=8, disc_channels=4, upsample="nearest", l_scale=True)


def module(seed: int, **settings) -> Pix2PixModule:
    torch.manual_seed(seed)
    made = Pix2PixModule(**TINY, **settings)
    for parameter in made.generator.full_res_parameters():  # the path starts at zero: give it a function
        torch.nn.init.normal_(parameter, std=0.1)
    return made.eval()


def test_the_grafted_generator_reads_l_from_one_and_ab_from_the_other(tmp_path):
    density = module(0, full_res_channels=4, full_res_stride=4)
    correlation = module(1, correlation_encoder=True, correlation_stride=4)
    save_module_checkpoint(density, tmp_path / "density.ckpt")
    save_module_checkpoint(correlation, tmp_path / "correlation.ckpt")
    assert main([str(tmp_path / "density.ckpt"), str(tmp_path / "correlation.ckpt"), str(tmp_path / "out.ckpt")]) == 0
    grafted = load_module(tmp_path / "out.ckpt").eval()
    assert grafted.hparams.full_res_stride == 4 and grafted.hparams.correlation_stride == 4
    raster = torch.from_numpy((np.random.default_rng(2).random((2, 1, 64, 64)) < 0.2).astype(np.float32))
    with torch.no_grad():
        (mixed, mixed_scale), (lab, scale), (other, _) = (m.generator.forward_with_scale(raster)
                                                           for m in (grafted, density, correlation))
    assert torch.equal(mixed[:, :1], lab[:, :1]) and torch.equal(mixed_scale, scale)
    assert torch.equal(mixed[:, 1:], other[:, 1:])
    assert not torch.equal(lab[:, 1:], other[:, 1:])  # the two sources differ, so the test can tell them apart


def test_a_branch_that_reads_the_shared_encoder_is_refused(tmp_path, capsys):
    density = module(0)
    save_module_checkpoint(density, tmp_path / "a.ckpt")
    save_module_checkpoint(module(1), tmp_path / "b.ckpt")  # its correlation decoder reads the shared encoder
    save_module_checkpoint(module(1, correlation_encoder=True, correlation_shared_levels=2), tmp_path / "c.ckpt")
    for source in ("b.ckpt", "c.ckpt"):
        assert main([str(tmp_path / "a.ckpt"), str(tmp_path / source), str(tmp_path / "out.ckpt")]) == 2
        error = capsys.readouterr().err.strip()
        assert len(error.splitlines()) == 1 and "encoder all of its own" in error
    assert not (tmp_path / "out.ckpt").exists()
