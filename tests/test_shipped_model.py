"""The shipped model's headline figures on a reduced evaluation (about 25 s on one thread): a retrained
model that regresses fails here, and so does a model whose recorded evaluation (default.eval.json) is stale.

The reduced evaluation reuses ``python -m patternshop_nn.evaluate``'s machinery (:mod:`patternshop_nn.evaluate`,
:mod:`patternshop_nn.ood`) on:

* the first 4 held-out procedural pairs of the recorded evaluation (seed 1000, synthesiser only), scored by
  :func:`patternshop_nn.evaluate.score` against the best KDE and the palette decoding;
* 8 held-out pairs of other methods' patterns (seed 1000, ``other_methods.share=1.0``: no synthesis), the
  network's density and latent MAE;
* Poisson, jittered-grid and Thomas patterns at density 1.0 read by the network alone (``ood.infer``,
  ``raw``: one run, no calibration), the share of pixels whose nearest preset is the right one.

Measured with the shipped patternshop-procedural-v15 (ONNX Runtime, one thread; the functions below
on the same pairs, the degraded copies made as in :func:`test_a_degraded_model_fails_the_headline_figures`):

==========================================  ========  =========  =====================================
figure                                      measured  bound      degraded copies (weights x (1 + s N))
==========================================  ========  =========  =====================================
procedural density MAE (KDE 0.1005)         0.0687    <= 0.0742  s 0.02: 0.0798; 0.05: 0.1153
procedural latent MAE (palette 0.1220)      0.1331    <= 0.1437  s 0.05: 0.1419 (not a discriminating figure)
other methods: density MAE                  0.0456    <= 0.0492  s 0.02: 0.0506; 0.05: 0.0802
other methods: latent MAE                   0.0067    <= 0.0090  s 0.02: 0.0231; 0.05: 0.0746
stationary, network alone: right preset     1.0       >= 0.95    s 0.05: >= 0.9999
==========================================  ========  =========  =====================================

The MAE bounds are 8 % above the measurement (the other-method latent MAE, a small figure, 35 %). v15 reads the
synthesised procedural pairs better than v12 (0.0687 against v12's 0.0723 and v5's 0.0676 on these 4 pairs; v14
0.0672; see default.eval.json for the 24 and docs/network.md "Model v15") and the other methods' density and latent
a little worse (density 0.0456, latent 0.0067; v12 0.0442, 0.0055; v5's latent 0.0124). The per-pair figures of the
4 procedural pairs agree with default.eval.json's (made by the same code) to 1e-4, asserted to 0.003 and 0.004.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from data_gen.shards import load_pairs
from export.runtime import DEFAULT_MODEL, OnnxModel
from patternshop_nn import ood
from patternshop_nn.baselines import density_mae, latent_mae
from patternshop_nn.evaluate import make_pairs, predict_pairs, score
from synthesis.conventions import POINTS_PER_INK
from synthesis.palette import load_palette
from synthesis.points import PointSet

HELD_OUT_SEED = 1000  # python -m patternshop_nn.evaluate's default, and the recorded evaluation's
PROCEDURAL_PAIRS, OTHER_PAIRS = 4, 8
PROCESSES = ("poisson", "jitter", "thomas")  # at density 1.0; Poisson-disk and Lloyd cost 26 s and 6 s to make
BOUNDS = {  # figure: (bound, "max" or "min"); measurements in the module docstring
    "procedural_density_mae": (0.0742, "max"),
    "procedural_latent_mae": (0.1437, "max"),
    "other_density_mae": (0.0492, "max"),
    "other_latent_mae": (0.0090, "max"),
    **{f"right_preset_{process}": (0.95, "min") for process in PROCESSES},
}
RECORDED = json.loads((DEFAULT_MODEL.parent / "default.eval.json").read_text())


@pytest.fixture(scope="module")
def held_out(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(procedural pairs, other-method pairs) as the evaluation makes them, at the shipped model's scale."""
    root = tmp_path_factory.mktemp("held_out")
    dataset = ["dataset=procedural", f"synthesis.points_per_ink={OnnxModel().points_per_ink}"]
    return (make_pairs(root / "procedural", dataset, PROCEDURAL_PAIRS, HELD_OUT_SEED, 1),
            make_pairs(root / "other", [*dataset, "other_methods.share=1.0"], OTHER_PAIRS, HELD_OUT_SEED, 1))


def headline(model: OnnxModel, held_out: tuple[Path, Path]) -> dict:
    """The reduced evaluation's figures (see the module docstring)."""
    procedural = score(model, held_out[0])
    other = load_pairs(held_out[1])
    predicted, truth = predict_pairs(model, other), other.target.transpose(0, 3, 1, 2).astype(np.float32) / 255.0
    figures = {"procedural": procedural,
               "procedural_density_mae": procedural["model_density_mae"], "procedural_latent_mae": procedural["model_latent_mae"],
               "other_density_mae": density_mae(predicted, truth), "other_latent_mae": latent_mae(predicted, truth)}
    palette = load_palette()
    for process in PROCESSES:
        make, preset = ood.STATIONARY[process]
        lab_map = ood.infer(PointSet(make(POINTS_PER_INK, HELD_OUT_SEED)), model, raw=True).lab_map
        figures[f"right_preset_{process}"] = ood.nearest_preset_share(lab_map, palette, preset)
    return figures


def shortfalls(figures: dict) -> list[str]:
    """The figures past their bounds, as 'figure measured (bound)'."""
    return [f"{name} {figures[name]:.4f} ({'<=' if side == 'max' else '>='} {bound})" for name, (bound, side) in BOUNDS.items()
            if (figures[name] > bound if side == "max" else figures[name] < bound)]


def test_shipped_model_keeps_its_headline_figures(held_out: tuple[Path, Path]) -> None:
    figures = headline(OnnxModel(threads=1), held_out)
    assert shortfalls(figures) == []
    procedural = figures["procedural"]
    # density: better than the best KDE on the same pairs (recorded on 24 pairs: 37 % below it). Latent: the palette
    # baseline decodes 4 x 4 windows by their PCF since decoding became orientation free, and that baseline is now
    # about as good as the network on these 4 pairs, so the bound only guards against the network falling clearly behind
    # it. Measured gain: +0.22 against the old CNN-feature decoding; -0.042 with the PCF decoding; -0.125 since the
    # synthesiser's nearest-neighbour term (the pairs' patterns come closer to the palette's exemplars: the baseline's
    # latent MAE 0.125 -> 0.119, the network's, trained on the older synthesiser's pairs, 0.130 -> 0.134). v15: density
    # gain 0.316 (v14 0.331, v12 0.281, v11 0.248, v10 0.271, v5 0.34), latent gain -0.091 (v14 -0.074, v12 -0.107).
    assert procedural["density_gain_vs_kde"] > 0.22 and procedural["latent_gain_vs_baseline"] > -0.16
    # the recorded evaluation is this model's: its first pairs score, on average, what default.eval.json says. The pairs
    # are remade by today's synthesiser, so single pairs move with it (tone term and ink hold: up to 0.0041 density
    # MAE on one pair, 0.0007 on the mean of the four); a stale eval file or another model moves the mean further.
    recorded = RECORDED["procedural"]
    for key, tolerance in (("per_pair_model_density_mae", 0.003), ("per_pair_model_latent_mae", 0.004)):
        assert np.mean(procedural[key]) == pytest.approx(np.mean(recorded[key][:PROCEDURAL_PAIRS]), abs=tolerance), key


def test_a_degraded_model_fails_the_headline_figures(held_out: tuple[Path, Path], tmp_path: Path) -> None:
    """The shipped weights each multiplied by (1 + 0.05 N(0, 1)): measured other-method density 0.0802, latent 0.0746 (v15)."""
    import onnx
    from onnx import numpy_helper

    graph = onnx.load(str(DEFAULT_MODEL))
    rng = np.random.default_rng(0)
    for initializer in graph.graph.initializer:
        weights = numpy_helper.to_array(initializer)
        if weights.dtype.kind == "f" and weights.size > 1:
            noisy = weights * (1 + 0.05 * rng.standard_normal(weights.shape))
            initializer.CopyFrom(numpy_helper.from_array(noisy.astype(weights.dtype), initializer.name))
    onnx.save(graph, str(tmp_path / "degraded.onnx"))
    failed = {entry.split()[0] for entry in shortfalls(headline(OnnxModel(tmp_path / "degraded.onnx", threads=1), held_out))}
    assert {"other_density_mae", "other_latent_mae"} <= failed
