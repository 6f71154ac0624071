"""Training the correlation decoder alone (``python -m patternshop_nn.tune_correlation``)."""

from __future__ import annotations

import numpy as np
import torch

from data_gen.shards import Pairs
from patternshop_nn.data import dihedral
from patternshop_nn.module import Pix2PixModule
from patternshop_nn.onnx_export import export_onnx
from patternshop_nn.tune_correlation import TuneSettings, folder_features, main, tune_correlation

SIDE = 64


def model() -> Pix2PixModule:
    torch.manual_seed(0)
    return Pix2PixModule(base_channels=4, max_channels=8, disc_channels=4, upsample="nearest", l_scale=True,
                         full_res_channels=4).eval()


def pair_folder(folder, pairs: int = 16, seed: int = 1):
    """Rasters of random density, all with the colour z = (200, 60) / 255: what a fresh decoder (about 128) must learn."""
    rng = np.random.default_rng(seed)
    folder.mkdir()
    density = rng.uniform(0.02, 0.3, (pairs, 1, 1))
    raster = (rng.random((pairs, SIDE, SIDE)) < density).astype(np.float16)
    target = np.zeros((pairs, SIDE, SIDE, 3), np.uint8)
    target[..., 0] = 128
    target[..., 1] = 200
    target[..., 2] = 60
    Pairs(np.arange(pairs), raster, target, np.zeros((0, 2), np.float32), np.zeros(pairs + 1, np.int64),
          [{} for _ in range(pairs)]).write(folder / "pairs-00000.npz")
    return folder


def test_only_the_correlation_decoder_learns_and_its_error_falls(tmp_path):
    tuned, original = model(), model()
    settings = TuneSettings(steps=100, batch_size=4, lr=3e-2, val_fraction=0.25)
    rng = torch.Generator().manual_seed(0)
    folders = [folder_features(tuned.generator, pair_folder(tmp_path / name, seed=k), settings, rng)
               for k, name in enumerate(("one", "two"))]
    report = tune_correlation(tuned, folders, settings)
    for name in (str(tmp_path / "one"), str(tmp_path / "two")):  # held out, a and b much nearer their targets
        assert report["held_out_ab_error"][name] < 0.3 * report["held_out_ab_error_before"][name]
    changed = [k for k, v in tuned.state_dict().items() if not torch.equal(v, original.state_dict()[k])]
    assert changed and all(k.startswith("generator.correlation.") for k in changed)
    assert not any("running_" in k for k in changed)  # batch-norm statistics as they were
    x = torch.from_numpy(np.load(tmp_path / "one" / "pairs-00000.npz")["raster"][:2].astype(np.float32))[:, None]
    with torch.no_grad():
        (lab, scale), (want_lab, want_scale) = tuned.generator.forward_with_scale(x), original.generator.forward_with_scale(x)
    torch.testing.assert_close(lab[:, :1], want_lab[:, :1], rtol=0, atol=0)  # L and its scale: bit for bit
    torch.testing.assert_close(scale, want_scale, rtol=0, atol=0)
    assert not torch.equal(lab[:, 1:], want_lab[:, 1:])
    assert all(p.requires_grad for p in tuned.parameters())  # the module is left trainable as it came


def assert_the_command_writes_a_checkpoint_that_exports(command, record: str, printed: str, tmp_path, capsys) -> None:
    """``command`` (a tool's ``main``) on a fresh model and one folder, 3 steps: it prints ``printed``, its checkpoint
    keeps the settings and folders under ``record`` and exports to ONNX."""
    original = model()
    checkpoint = tmp_path / "model.ckpt"
    torch.save({"state_dict": original.state_dict(), "hyper_parameters": dict(original.hparams),
                "pytorch-lightning_version": "2"}, checkpoint)
    folder = pair_folder(tmp_path / "pairs")
    out = tmp_path / "tuned.ckpt"
    assert command([str(checkpoint), str(out), "--pairs", str(folder), "--steps", "3", "--batch-size", "2"]) == 0
    assert printed in capsys.readouterr().out
    saved = torch.load(out, weights_only=False)
    assert saved[record]["steps"] == 3 and saved[record]["folders"] == [str(folder)]
    export_onnx(out, tmp_path / "tuned.onnx", {"points_per_ink": 8000})
    assert (tmp_path / "tuned.onnx").stat().st_size > 0


def test_the_command_writes_a_checkpoint_that_exports(tmp_path, capsys):
    assert_the_command_writes_a_checkpoint_that_exports(main, "correlation_tuning", "held-out |a, b - target|", tmp_path, capsys)


def test_a_folder_without_pairs_is_one_line(tmp_path, capsys):
    original = model()
    checkpoint = tmp_path / "model.ckpt"
    torch.save({"state_dict": original.state_dict(), "hyper_parameters": dict(original.hparams),
                "pytorch-lightning_version": "2"}, checkpoint)
    (tmp_path / "empty").mkdir()
    assert main([str(checkpoint), str(tmp_path / "out.ckpt"), "--pairs", str(tmp_path / "empty")]) == 2
    err = capsys.readouterr().err
    assert "no pair shards" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out.ckpt").exists()


def test_two_views_are_a_symmetry_and_its_transpose_held_out_by_pair(tmp_path):
    folder = pair_folder(tmp_path / "pairs", pairs=8)
    with np.load(folder / "pairs-00000.npz") as shard:  # a, b vary along x, so a transpose shows
        arrays = dict(shard)
    arrays["target"][..., 1] = np.arange(SIDE, dtype=np.uint8)[None, None, :] * 3
    np.savez(folder / "pairs-00000.npz", **arrays)
    generator = model().generator
    data = folder_features(generator, folder, TuneSettings(views=2, val_fraction=0.25), torch.Generator().manual_seed(0))
    assert len(data.targets) == 16
    first, second = data.targets[0::2].float(), data.targets[1::2].float()
    torch.testing.assert_close(second, first.transpose(-1, -2), rtol=0, atol=0)
    assert not torch.equal(first, second)
    held, train = set(data.held_out.tolist()), set(data.train.tolist())
    assert held.isdisjoint(train) and held | train == set(range(16)) and len(held) == 4
    assert {k // 2 for k in held}.isdisjoint({k // 2 for k in train})  # both views of a pair on one side
    raster = torch.from_numpy(arrays["raster"][:1].astype(np.float32))[:, None]
    with torch.no_grad():  # the first pair's views: its raster under some symmetry, then that transposed
        seen = [dihedral(raster, code) for code in range(8)]
        first_view = [view for view in seen if torch.equal(generator._encode(view)[0].half(), data.features[0][:1])]
        assert len(first_view) == 1
        want = generator._encode(first_view[0].transpose(-1, -2))[0].half()
    torch.testing.assert_close(data.features[0][1:2], want, rtol=0, atol=0)
