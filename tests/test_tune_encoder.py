"""Training the encoder with the correlation decoder, L held (``python -m patternshop_nn.tune_encoder``)."""

from __future__ import annotations

import torch
from test_tune_correlation import assert_the_command_writes_a_checkpoint_that_exports, model, pair_folder

from patternshop_nn.tune_encoder import EncoderSettings, folder_pairs, main, tune_encoder


def tuned(tmp_path, l_weight: float):
    """(report, tuned module, starting module) after 60 steps on two folders."""
    module, original = model(), model()
    settings = EncoderSettings(steps=60, batch_size=4, lr=1e-2, val_fraction=0.25, l_weight=l_weight)
    rng = torch.Generator().manual_seed(0)
    folders = [folder_pairs(original.generator.eval(), pair_folder(tmp_path / f"{name}{l_weight}", seed=k), settings, rng)
               for k, name in enumerate(("one", "two"))]
    return tune_encoder(module, folders, settings), module, original


def test_the_encoder_and_correlation_decoder_learn_and_the_rest_stays(tmp_path):
    report, module, original = tuned(tmp_path, l_weight=1.0)
    for name, before in report["held_out_ab_error_before"].items():
        assert report["held_out_ab_error"][name] < 0.3 * before
    changed = {k.split(".")[1] for k, v in module.state_dict().items() if not torch.equal(v, original.state_dict()[k])}
    assert changed == {"first", "downs", "correlation"}
    assert not any("running_" in k for k, v in module.state_dict().items() if not torch.equal(v, original.state_dict()[k]))
    assert all(p.requires_grad for p in module.parameters())  # left trainable as it came


def test_the_l_term_holds_l_to_the_starting_model(tmp_path):
    held = tuned(tmp_path, l_weight=10.0)[0]["held_out_l_change"]
    free = tuned(tmp_path, l_weight=0.0)[0]["held_out_l_change"]
    assert all(held[name] < 0.5 * free[name.replace("10.0", "0.0")] for name in held), (held, free)


def test_the_command_writes_a_checkpoint_that_exports(tmp_path, capsys):
    assert_the_command_writes_a_checkpoint_that_exports(main, "encoder_tuning", "held-out |L - the model's L|", tmp_path, capsys)
