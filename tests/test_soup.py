"""`python -m patternshop_nn.soup`: weight interpolation of two checkpoints of one lineage."""

from __future__ import annotations

import lightning
import pytest
from helpers import run_cli
import torch

from export.runtime import OnnxModel
from patternshop_nn.module import Pix2PixModule
from patternshop_nn.onnx_export import load_generator
from patternshop_nn.soup import interpolate_state_dicts, main
from synthesis.errors import PatternshopError


def tiny_checkpoint(path, seed: int, **kwargs) -> dict:
    """A tiny l_scale Pix2PixModule checkpoint with random weights and batch-norm statistics; returns its dict."""
    torch.manual_seed(seed)
    module = Pix2PixModule(**{"base_channels": 4, "max_channels": 8, "disc_channels": 4, "upsample": "nearest",
                              "l_scale": True, **kwargs})
    state = module.state_dict()
    for key, tensor in state.items():
        if tensor.is_floating_point():
            tensor.copy_(torch.rand_like(tensor) + (0.5 if key.endswith("running_var") else 0.0))
        elif key.endswith("num_batches_tracked"):
            tensor.fill_(seed)
    checkpoint = {"pytorch-lightning_version": lightning.__version__, "epoch": seed, "global_step": 10 * seed,
                  "state_dict": state, "hparams_name": "kwargs", "hyper_parameters": dict(module.hparams)}
    torch.save(checkpoint, path)
    return checkpoint


@pytest.fixture()
def pair(tmp_path):
    """Two checkpoints of one architecture whose training hyper-parameters differ (as v7b's and v9b's)."""
    a = tiny_checkpoint(tmp_path / "a.ckpt", 1, lr=3e-5)
    b = tiny_checkpoint(tmp_path / "b.ckpt", 2, lr=1e-4, blurred_l1_weight=0.4)
    return tmp_path / "a.ckpt", tmp_path / "b.ckpt", a["state_dict"], b["state_dict"]


def soup(a, b, alpha: float, out) -> dict:
    assert main([str(a), str(b), "--alpha", str(alpha), str(out)]) == 0
    return torch.load(out, map_location="cpu", weights_only=False)


def test_alpha_0_gives_a_1_gives_b_and_half_the_mean(pair, tmp_path):
    a, b, sa, sb = pair
    for alpha, expected in ((0.0, lambda k: sa[k]), (1.0, lambda k: sb[k]), (0.5, lambda k: (sa[k] + sb[k]) / 2)):
        out = soup(a, b, alpha, tmp_path / f"s{alpha}.ckpt")
        mixed = out["state_dict"]
        assert list(mixed) == list(sb)
        for key, tensor in mixed.items():
            if tensor.is_floating_point():
                torch.testing.assert_close(tensor, expected(key), rtol=0, atol=1e-7)
            else:
                assert torch.equal(tensor, sb[key])  # integer buffers are B's
        assert any("running_mean" in k for k in mixed)  # batch-norm statistics are interpolated too
        assert out["soup"] == {"a": str(a), "b": str(b), "alpha": alpha}
        assert out["epoch"] == 2 and out["global_step"] == 20 and out["hyper_parameters"]["lr"] == 1e-4
        for key in ("pytorch-lightning_version", "hparams_name"):
            assert key in out


def test_the_soup_loads_and_exports(pair, tmp_path, capsys):
    a, b, sa, sb = pair
    out = tmp_path / "soup.ckpt"
    soup(a, b, 0.85, out)
    generator = load_generator(out)
    key = next(k for k in sa if k.startswith("generator.") and sa[k].is_floating_point())
    torch.testing.assert_close(generator.state_dict()[key[len("generator."):]], 0.15 * sa[key] + 0.85 * sb[key])
    status, _, err = run_cli(["export", str(out), str(tmp_path / "soup.onnx"), "--name", "soup",
                              "--set", "points_per_ink=8000"], capsys)
    assert status == 0, err
    assert OnnxModel(tmp_path / "soup.onnx").metadata["name"] == "soup"


def test_mismatched_checkpoints_are_refused_in_one_line(pair, tmp_path, capsys):
    a, b, sa, sb = pair
    tiny_checkpoint(tmp_path / "wide.ckpt", 3, max_channels=16)
    tiny_checkpoint(tmp_path / "plain.ckpt", 4)
    plain = torch.load(tmp_path / "plain.ckpt", weights_only=False)
    plain["hyper_parameters"]["l_scale"] = False  # same tensors claimed, another architecture
    torch.save(plain, tmp_path / "plain.ckpt")
    for other, reason in ((tmp_path / "wide.ckpt", "max_channels"), (tmp_path / "plain.ckpt", "l_scale"),
                          (tmp_path / "missing.ckpt", "no such checkpoint")):
        assert main([str(a), str(other), "--alpha", "0.5", str(tmp_path / "out.ckpt")]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and reason in err, err
    assert main([str(a), str(b), "--alpha", "1.5", str(tmp_path / "out.ckpt")]) == 2
    assert "alpha" in capsys.readouterr().err
    assert not (tmp_path / "out.ckpt").exists()


def test_interpolate_state_dicts_refuses_other_keys_and_shapes():
    a = {"w": torch.zeros(2, 3), "n": torch.tensor(1)}
    with pytest.raises(PatternshopError, match="different tensors"):
        interpolate_state_dicts(a, {"w": torch.zeros(2, 3)}, 0.5)
    with pytest.raises(PatternshopError, match="shapes differ"):
        interpolate_state_dicts(a, {"w": torch.zeros(3, 2), "n": torch.tensor(2)}, 0.5)
    mixed = interpolate_state_dicts(a, {"w": torch.ones(2, 3), "n": torch.tensor(2)}, 0.25)
    assert torch.equal(mixed["w"], torch.full((2, 3), 0.25)) and mixed["n"].item() == 2
