"""Training the correlation decoder with an encoder of its own (``python -m patternshop_nn.tune_encoder``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_tune_correlation import assert_the_command_writes_a_checkpoint_that_exports, model, pair_folder

from data_gen.shards import read_shard
from patternshop_nn.onnx_export import load_module
from patternshop_nn.tune_encoder import EncoderSettings, _ab_error, edge_mask, folder_pairs, main, tune_encoder
from synthesis.errors import PatternshopError


@pytest.mark.parametrize(("shared_levels", "stride", "kept"), [(0, 1, 0.3), (2, 1, 0.7), (0, 8, 0.7)])  # kept: error bound
def test_the_own_encoder_and_correlation_decoder_learn_and_l_stays_bit_for_bit(tmp_path, shared_levels, stride, kept):
    module, original = model(), model()
    settings = EncoderSettings(steps=60, batch_size=4, lr=1e-2, val_fraction=0.25, shared_levels=shared_levels,
                               correlation_stride=stride)
    rng = torch.Generator().manual_seed(0)
    folders = [folder_pairs(pair_folder(tmp_path / name, seed=k), settings, rng) for k, name in enumerate(("one", "two"))]
    report = tune_encoder(module, folders, settings)
    for name, before in report["held_out_ab_error_before"].items():
        assert report["held_out_ab_error"][name] < kept * before  # fewer layers (or a new head) learn less in 60 steps
    state, start = module.state_dict(), original.state_dict()
    changed = {k for k in state if k not in start or not torch.equal(state[k], start[k])}
    assert changed and all(k.startswith(("generator.correlation_encoder.", "generator.correlation.")) for k in changed)
    assert not any("running_" in k and k in start for k in changed)  # batch-norm statistics as they were
    assert module.hparams["correlation_encoder"] and module.hparams["correlation_shared_levels"] == shared_levels
    assert module.hparams["correlation_stride"] == stride == module.generator.correlation.stride
    x = folders[0].raster[:2].float()
    with torch.no_grad():
        (lab, scale), (want_lab, want_scale) = module.generator.forward_with_scale(x), original.generator.eval().forward_with_scale(x)
    torch.testing.assert_close(lab[:, :1], want_lab[:, :1], rtol=0, atol=0)
    torch.testing.assert_close(scale, want_scale, rtol=0, atol=0)
    assert not torch.equal(lab[:, 1:], want_lab[:, 1:])


def test_the_command_writes_a_checkpoint_that_exports_and_reloads_with_its_encoder(tmp_path, capsys):
    assert_the_command_writes_a_checkpoint_that_exports(main, "encoder_tuning", "held-out |a, b - target|", tmp_path, capsys)
    assert load_module(tmp_path / "tuned.ckpt").generator.correlation_encoder is not None


def test_folder_weights_decide_which_folder_trains_and_bad_settings_are_refused(tmp_path):
    settings = EncoderSettings(steps=20, batch_size=2, lr=1e-2, val_fraction=0.25)
    rng = torch.Generator().manual_seed(0)
    folders = [folder_pairs(pair_folder(tmp_path / name, seed=k), settings, rng) for k, name in enumerate(("one", "two"))]
    only_two = EncoderSettings(**{**settings.__dict__, "folder_weights": (0.0, 1.0)})
    report = tune_encoder(model(), folders, only_two)
    one, two = (str(tmp_path / name) for name in ("one", "two"))
    gain = {name: report["held_out_ab_error_before"][name] - report["held_out_ab_error"][name] for name in (one, two)}
    assert gain[two] > 0 and gain[two] > gain[one]  # a weight of 0 never draws the folder
    for bad in ((1.0,), (1.0, -1.0), (0.0, 0.0)):
        with pytest.raises(PatternshopError, match="folder-weights"):
            tune_encoder(model(), folders, EncoderSettings(**{**settings.__dict__, "folder_weights": bad}))
    for bad in (3, 0, 64):  # not a power of 2; beyond the deepest level
        with pytest.raises(PatternshopError, match="correlation-stride"):
            tune_encoder(model(), folders, EncoderSettings(**{**settings.__dict__, "correlation_stride": bad}))


def test_edge_mask_marks_inked_pixels_near_a_correlation_edge():
    target = np.zeros((1, 8, 40, 3), np.uint8)
    target[..., 0] = 128  # density 0.5: inked
    target[..., 1] = 100
    target[:, :, 20:, 1] = 140  # a jumps by 40 ab units between columns 19 and 20
    target[:, :, 35:, 0] = 255  # white on the right: never weighed
    mask = edge_mask(target, reach_px=3)
    assert mask.shape == (1, 1, 8, 40) and mask.dtype == bool
    assert mask[0, 0, 0].nonzero()[0].tolist() == [17, 18, 19, 20, 21, 22]  # distance 0, 1, 2 on either side


def test_the_edge_weight_weighs_the_near_pixels_and_a_tune_with_it_learns(tmp_path):
    settings = EncoderSettings(steps=30, batch_size=4, lr=1e-2, val_fraction=0.25, edge_weight=3.0, edge_reach_px=4.0)
    rng = torch.Generator().manual_seed(0)
    folder = pair_folder(tmp_path / "one", seed=0)
    pairs = read_shard(folder / "pairs-00000.npz")
    pairs.target[:, :, 16:, 1] = 120  # the right three quarters another colour: an edge at column 16
    pairs.write(folder / "pairs-00000.npz")
    data = folder_pairs(folder, settings, rng)
    assert data.near_edge is not None and data.near_edge.shape[0] == data.raster.shape[0] and data.near_edge.any()
    module = model()
    generator = module.generator.eval()
    index = data.train[:3]
    with torch.no_grad():
        error = (torch.sigmoid(generator.correlation_logits(data.raster[index].float())) - data.ab[index].float()).abs()
        weight = 1 + 3.0 * data.near_edge[index].float()
        want = float((error * weight).sum() / (weight.sum() * 2))
        assert float(_ab_error(generator, data, index, [0, 0, 0], 3.0)) == pytest.approx(want, rel=1e-5)
        assert float(_ab_error(generator, data, index, [0, 0, 0])) == pytest.approx(float(error.mean()), rel=1e-5)
        assert want != pytest.approx(float(error.mean()), rel=1e-3)
    report = tune_encoder(module, [data], settings)
    assert report["held_out_ab_error"][data.name] < report["held_out_ab_error_before"][data.name]
    unweighted = folder_pairs(folder, EncoderSettings(), torch.Generator().manual_seed(0))
    assert unweighted.near_edge is None
    with pytest.raises(PatternshopError, match="edge-weight"):
        tune_encoder(model(), [unweighted], settings)
