"""The network (issue 6): shapes and ranges, the two branches, overfitting one batch, data, baselines, train.py."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader, TensorDataset

from data_gen.pairs import generate
from data_gen.provenance import compose_config
from data_gen.shards import load_pairs
from patternshop_nn.baselines import (
    correlation_edge_distance,
    density_mae,
    kde_density,
    latent_error_by_edge_distance,
    latent_mae,
    windowed_latent,
)
from patternshop_nn.data import PairDataModule, PairDataset, dihedral, split_items
from patternshop_nn.module import Pix2PixModule
from patternshop_nn.networks import DualBranchUNet, GANLoss, NearestUpConv, PatchDiscriminator, fuse_upsampling
from synthesis.generators import generate as generate_points
from synthesis.palette import ab_to_latent, load_palette
from synthesis.raster import point_raster

ROOT = Path(__file__).resolve().parent.parent
TINY_MODEL = ["model.base_channels=4", "model.max_channels=8", "model.disc_channels=4"]
TINY_PAIRS = ["pairs.num_items=8", "pairs.workers=1", "pairs.map_size=64", "pairs.raster_size=64",
              "pairs.synthesis.points_per_ink=1500", "pairs.synthesis.iterations=10"]


@pytest.fixture(scope="module")
def pair_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """8 procedural pairs of 64 x 64 (made once for this module)."""
    folder = tmp_path_factory.mktemp("pairs")
    generate(compose_config("pairs", [f"out_dir={folder}", "num_items=8", "workers=1", "map_size=64", "raster_size=64",
                                      "synthesis.points_per_ink=1500", "synthesis.iterations=10"]))
    return folder


# --- networks --------------------------------------------------------------------
@pytest.mark.parametrize("side", [64, 128])
def test_generator_shape_and_range(side: int) -> None:
    net = DualBranchUNet(base_channels=4, max_channels=16).eval()
    with torch.no_grad():
        out = net(torch.rand(2, 1, side, side))
    assert out.shape == (2, 3, side, side)
    assert out.min() >= 0 and out.max() <= 1


def test_generator_needs_a_multiple_of_64() -> None:
    with pytest.raises(ValueError, match="divisible by 64"):
        DualBranchUNet(base_channels=4, max_channels=8)(torch.rand(1, 1, 96, 96))


def test_branches_are_separate() -> None:
    """Channel 0 comes from the density decoder alone, channels 1-2 from the correlation decoder alone."""
    net = DualBranchUNet(base_channels=4, max_channels=8).eval()
    x = torch.rand(1, 1, 64, 64)
    with torch.no_grad():
        before = net(x)
        for parameter in net.correlation.parameters():
            parameter.add_(torch.randn_like(parameter))
        after = net(x)
    assert torch.equal(before[:, 0], after[:, 0])
    assert not torch.allclose(before[:, 1:], after[:, 1:])


def test_discriminator_patches() -> None:
    disc = PatchDiscriminator(4, base_channels=8, layers=3)
    assert disc(torch.rand(2, 1, 128, 128), torch.rand(2, 3, 128, 128)).shape == (2, 1, 14, 14)


def test_gan_loss_modes() -> None:
    logits = torch.zeros(3, 1, 4, 4)
    assert GANLoss("vanilla")(logits, True).item() == pytest.approx(np.log(2), rel=1e-5)
    assert GANLoss("lsgan")(logits, True).item() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="unknown GAN loss"):
        GANLoss("wgan")


class _StepLosses(L.Callback):
    def __init__(self) -> None:
        self.l1: list[float] = []

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_index) -> None:  # noqa: ANN001
        self.l1.append(float(trainer.callback_metrics["train/l1_step"]))


def test_one_batch_overfits() -> None:
    """The full GAN step (both optimisers) drives the L1 loss on one fixed batch down by at least half."""
    torch.manual_seed(0)
    raster = (torch.rand(4, 1, 64, 64) < torch.linspace(0.05, 0.3, 4).view(4, 1, 1, 1)).float()  # 4 densities
    level = raster.mean(dim=(1, 2, 3)).view(4, 1, 1, 1).expand(4, 1, 64, 64)
    target = torch.cat([1 - 2 * level, 0.3 + level, torch.full_like(level, 0.6)], 1)
    loader = DataLoader(TensorDataset(raster, target), batch_size=4)
    model = Pix2PixModule(base_channels=8, max_channels=16, disc_channels=4, lr=2e-3)
    losses = _StepLosses()
    trainer = L.Trainer(max_steps=2 * 50, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, callbacks=[losses])
    trainer.fit(model, train_dataloaders=loader)
    assert len(losses.l1) == 50
    assert np.mean(losses.l1[-5:]) <= 0.5 * losses.l1[0]


# --- data ------------------------------------------------------------------------
def test_dihedral_group() -> None:
    x = torch.arange(12.0).reshape(1, 3, 4)
    images = {tuple(dihedral(torch.arange(16.0).reshape(1, 4, 4), code).flatten().tolist()) for code in range(8)}
    assert len(images) == 8
    assert torch.equal(dihedral(x, 4), x.transpose(-1, -2))


def test_split_is_fixed_by_item_number() -> None:
    train, val = split_items(np.arange(40), 0.1)
    assert val.tolist() == [9, 19, 29, 39] and len(train) == 36
    # more items keep the old split
    train2, val2 = split_items(np.arange(60), 0.1)
    assert set(val.tolist()) <= set(val2.tolist())
    with pytest.raises(ValueError):
        split_items(np.arange(5), 1.5)


def test_crops_and_symmetries_keep_raster_and_map_aligned(pair_dir: Path) -> None:
    pairs = load_pairs(pair_dir)
    pairs.target[..., 1] = np.rint(pairs.raster.astype(np.float32) * 255).clip(0, 255).astype(np.uint8)  # map channel a = raster
    dataset = PairDataset(pairs, augment=True, crop=32)
    for k in range(len(dataset)):
        raster, target = dataset[k]
        assert raster.shape == (1, 32, 32) and target.shape == (3, 32, 32)
        assert torch.allclose(target[1], torch.round(raster[0] * 255) / 255, atol=1e-6)


def test_datamodule_and_cached_baselines(pair_dir: Path) -> None:
    module = PairDataModule(pair_dir, batch_size=2, val_fraction=0.25, baseline_cells=2)
    module.setup("fit")
    assert len(module.train_set) == 6 and len(module.val_set) == 2
    raster, target = next(iter(module.train_dataloader()))
    assert raster.shape == (2, 1, 64, 64) and target.shape == (2, 3, 64, 64)
    assert 0 <= float(target.min()) and float(target.max()) <= 1
    metrics = module.baseline_metrics
    assert set(metrics) == {"kde_density_mae", "kde_bandwidth_px", "baseline_latent_mae", "pairs"}
    assert 0 < metrics["kde_density_mae"] < 0.5 and metrics["pairs"] == 2
    cached = json.loads((pair_dir / "baselines.json").read_text())
    assert cached["metrics"] == metrics


def test_extra_pair_folders_add_training_pairs_only(pair_dir: Path, tmp_path: Path) -> None:
    extra = tmp_path / "extra"
    generate(compose_config("pairs", [f"out_dir={extra}", "num_items=4", "workers=1", "map_size=64", "raster_size=64", "seed=1",
                                      "synthesis.points_per_ink=1500", "other_methods.share=1.0"]))
    plain = PairDataModule(pair_dir, batch_size=2, val_fraction=0.25, baselines=False)
    plain.setup("fit")
    module = PairDataModule(pair_dir, batch_size=2, val_fraction=0.25, baselines=False, extra_pairs_dirs=[extra])
    module.setup("fit")
    assert len(module.train_set) == len(plain.train_set) + 4
    assert np.array_equal(module.val_set.indices, plain.val_set.indices)  # validation: pairs_dir's alone
    extra_pairs = load_pairs(extra)
    extra_positions = module.train_set.indices[-4:]
    assert np.array_equal(module.pairs.target[extra_positions], extra_pairs.target)
    assert np.array_equal(module.pairs.raster[extra_positions], extra_pairs.raster)
    small = tmp_path / "small"
    generate(compose_config("pairs", [f"out_dir={small}", "num_items=2", "workers=1", "map_size=32", "raster_size=32",
                                      "synthesis.points_per_ink=400", "other_methods.share=1.0"]))
    from synthesis.errors import PatternshopError

    with pytest.raises(PatternshopError, match="raster_size = 64"):
        PairDataModule(pair_dir, batch_size=2, val_fraction=0.25, baselines=False, extra_pairs_dirs=[small]).setup("fit")


# --- baselines -------------------------------------------------------------------
def test_kde_recovers_a_flat_density() -> None:
    rng = np.random.default_rng(0)
    points_per_ink, density = 8000, 0.4  # the default model's scale: 0.05 points per pixel, the clip never binds
    xy = rng.random((int(points_per_ink * density), 2))
    estimate = kde_density(point_raster(xy, 256), points_per_ink, 4.0)
    assert abs(float(estimate[16:-16, 16:-16].mean()) - density) < 0.02


def test_metrics() -> None:
    target = np.zeros((3, 4, 4))
    target[0, :, :2] = 1.0  # left half white: no density, latent not counted
    predicted = target.copy()
    predicted[1:, :, :2] += 0.5  # error where white only
    assert latent_mae(predicted, target) == 0.0
    predicted[1, :, 2:] += 0.2
    assert latent_mae(predicted, target) == pytest.approx(0.1)
    assert density_mae(predicted, target) == 0.0


def test_windowed_latent_finds_blue_noise() -> None:
    palette = load_palette()
    blue = ab_to_latent(np.array(palette.preset_ab()["blue"]))
    red = ab_to_latent(np.array(palette.preset_ab()["red"]))
    field = windowed_latent(generate_points("blue", 2000, seed=1), 64, palette, cells=2)
    assert field.shape == (64, 64, 2)
    assert np.linalg.norm(field.reshape(-1, 2).mean(0) - blue) < np.linalg.norm(blue - red) / 2


# --- train.py ----------------------------------------------------------------------
def _train(tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    args = [sys.executable, str(ROOT / "train.py"), f"run_dir={tmp_path / 'run'}", f"pairs.out_dir={tmp_path / 'pairs'}",
            *TINY_PAIRS, *TINY_MODEL, "data.batch_size=2", "data.val_fraction=0.25", "data.crop=null",
            "data.baseline_cells=2", "trainer.enable_progress_bar=false", "checkpoint_every_n_steps=4", *extra]
    return subprocess.run(args, capture_output=True, text=True, timeout=300, cwd=tmp_path)


def test_train_end_to_end_and_resume(tmp_path: Path) -> None:
    first = _train(tmp_path, "trainer.max_epochs=1")
    assert first.returncode == 0, first.stderr[-2000:]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["global_step"] == 6  # 3 batches x 2 optimiser steps
    last = torch.load(tmp_path / "run" / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 6  # the final weights, though 4 (checkpoint_every_n_steps) does not divide 6
    assert "current_model_state" not in last  # no weight averaging unless ema_decay is set
    assert (tmp_path / "run" / "checkpoints" / "best.ckpt").is_file()
    assert list((tmp_path / "run" / "logs").glob("version_*/samples/epoch0000.png"))
    assert {"val/density_mae", "val/latent_mae", "val/kde_density_mae", "val/baseline_latent_mae"} <= set(summary["val_metrics"])

    second = _train(tmp_path, "trainer.max_epochs=2")
    assert second.returncode == 0, second.stderr[-2000:]
    resumed = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert resumed["resumed_from"].endswith("last.ckpt")
    assert resumed["global_step"] == 12 and resumed["epochs"] == 2


def test_training_in_bfloat16_writes_its_samples(tmp_path: Path) -> None:
    """bf16 mixed precision (a GPU's usual setting; Lightning runs it on the CPU too) must reach the sample PNGs."""
    run = _train(tmp_path, "trainer.max_epochs=1", "trainer.precision=bf16-mixed")
    assert run.returncode == 0, run.stderr[-2000:]
    assert list((tmp_path / "run" / "logs").glob("version_*/samples/epoch0000.png"))


def test_fine_tuning_starts_from_another_runs_weights_with_a_decaying_rate(tmp_path: Path) -> None:
    first = _train(tmp_path, "trainer.max_epochs=1")
    assert first.returncode == 0, first.stderr[-2000:]
    source = tmp_path / "run" / "checkpoints" / "last.ckpt"
    tuned = _train(tmp_path, "trainer.max_epochs=2", f"init_from={source}", f"run_dir={tmp_path / 'tuned'}",
                   "model.lr_policy=linear", "model.lr_decay_epochs=2")
    assert tuned.returncode == 0, tuned.stderr[-2000:]
    assert f"weights from {source}" in tuned.stderr
    summary = json.loads((tmp_path / "tuned" / "summary.json").read_text())
    assert summary["init_from"] == str(source) and summary["resumed_from"] is None and summary["global_step"] == 12
    missing = _train(tmp_path, f"init_from={tmp_path / 'nope.ckpt'}", f"run_dir={tmp_path / 'none'}")
    assert missing.returncode == 2 and "init_from: no such checkpoint" in missing.stderr


def _generator_distance(checkpoint: Path) -> float:
    """Largest |averaged - raw| over the generator's weights of a checkpoint written with ema_decay."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    averaged, raw = state["state_dict"], state["current_model_state"]
    return max(float((averaged[k].float() - raw[k].float()).abs().max()) for k in raw if k.startswith("generator."))


def test_ema_checkpoints_hold_a_moving_average_whose_lag_grows_with_the_decay(tmp_path: Path) -> None:
    runs = {}
    for decay in ("0.5", "0.999"):  # the same seeded run twice: the raw weights are the same, only the average differs
        run = _train(tmp_path, "trainer.max_epochs=1", f"ema_decay={decay}", f"run_dir={tmp_path / decay}")
        assert run.returncode == 0, run.stderr[-2000:]
        runs[decay] = _generator_distance(tmp_path / decay / "checkpoints" / "last.ckpt")
    assert 0.0 < runs["0.5"] < runs["0.999"]
    best = torch.load(tmp_path / "0.5" / "checkpoints" / "best.ckpt", map_location="cpu", weights_only=False)
    assert "current_model_state" in best  # best.ckpt (chosen by validation) holds the average as its weights too
    bad = _train(tmp_path, "ema_decay=1.5", f"run_dir={tmp_path / 'bad'}", "data.generate=false")
    assert bad.returncode == 2 and "ema_decay must be between 0 and 1" in bad.stderr


def test_linear_policy_holds_then_decays_to_zero() -> None:
    module = Pix2PixModule(base_channels=4, max_channels=8, lr_policy="linear", lr_constant_epochs=2, lr_decay_epochs=4)
    optimizer = torch.optim.Adam(module.generator.parameters(), lr=1e-4)
    scheduler = module._scheduler(optimizer)
    rates = []
    for _ in range(8):
        rates.append(optimizer.param_groups[0]["lr"])
        optimizer.step()
        scheduler.step()
    assert rates == pytest.approx([1e-4, 1e-4, 1e-4, 0.75e-4, 0.5e-4, 0.25e-4, 0.0, 0.0])
    with pytest.raises(ValueError, match="lr_policy"):
        Pix2PixModule(lr_policy="cosine")


def test_train_user_error_is_one_line(tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, str(ROOT / "train.py"), "dataset=faces", f"run_dir={tmp_path / 'run'}"],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("train.py: error: dataset faces: set dataset.root=")


# --- stand-ins and evaluation --------------------------------------------------------
@pytest.mark.parametrize("layout", ["faces", "animals", "churches", "folder", "treecover"])
def test_standins_are_read_by_their_makers(layout: str, tmp_path: Path) -> None:
    from data_gen.makers import build_maker
    from data_gen.standins import write_standin

    root = write_standin(layout, tmp_path / layout, count=3, size=64)
    config = {"name": layout, "root": str(root)}
    if layout == "treecover":
        config["tile"] = 64
    maker = build_maker(config, 32)
    assert len(maker) == (6 if layout == "faces" else 3)  # faces: a uniform and a per-segment map per picture
    lab_map = maker.make(len(maker) - 1, np.random.default_rng(0))
    assert lab_map.lab.shape == (32, 32, 3)
    if layout == "faces":  # the per-segment map of a picture with several regions has several latents
        latents = np.unique(np.round(lab_map.latent().reshape(-1, 2), 4), axis=0)
        assert len(latents) >= 2


def test_score_compares_the_model_with_the_baselines(pair_dir: Path, tmp_path: Path) -> None:
    from patternshop_nn.onnx_export import export_onnx
    from export.runtime import OnnxModel
    from patternshop_nn.evaluate import score

    export_onnx(Pix2PixModule(base_channels=4, max_channels=8), tmp_path / "tiny.onnx", {"points_per_ink": 1500})
    result = score(OnnxModel(tmp_path / "tiny.onnx"), pair_dir, cells=2)
    assert result["pairs"] == 8 and len(result["per_pair_model_density_mae"]) == 8
    assert 0 < result["kde_density_mae"] < 0.5 and 0 < result["baseline_latent_mae"] < 0.5
    # models whose answer is known: the true maps score no error and gain 1; the KDE baseline itself gains 0
    pairs = load_pairs(pair_dir)
    truth = pairs.target.transpose(0, 3, 1, 2).astype(np.float32) / 255.0
    oracle = score(_FixedAnswers(pairs.raster, truth), pair_dir, cells=2)
    assert oracle["model_density_mae"] == 0 and oracle["model_latent_mae"] == 0 and max(oracle["per_pair_model_latent_mae"]) == 0
    assert oracle["density_gain_vs_kde"] == 1 and oracle["latent_gain_vs_baseline"] == 1
    assert all(row["mean_ab_error"] in (0, None) for row in oracle["model_ab_error_by_edge_distance"])
    assert sum(row["pixels"] for row in result["model_ab_error_by_edge_distance"]) > 0
    kde = truth.copy()
    kde[:, 0] = [1 - kde_density(raster, 1500, result["kde_bandwidth_px"]) for raster in pairs.raster]
    as_kde = score(_FixedAnswers(pairs.raster, kde), pair_dir, cells=2)
    assert as_kde["model_density_mae"] == pytest.approx(result["kde_density_mae"], abs=2e-5)
    assert abs(as_kde["density_gain_vs_kde"]) < 1e-3 and as_kde["latent_gain_vs_baseline"] == 1


def test_correlation_edge_distance_counts_pixels_from_the_edge() -> None:
    """Two regions side by side: the pixels on either side of the edge are at 0, the next at 1 ...; no edge: inf."""
    latent = np.zeros((2, 6, 10))
    latent[0, :, 4:] = 40 / 255  # a jumps by 40 ab units between columns 3 and 4
    latent[1, :, 4:] = 1 / 255  # a step under EDGE_JUMP_AB on its own adds nothing
    distance = correlation_edge_distance(latent)
    assert distance[:, 3].max() == 0 and distance[:, 4].max() == 0
    np.testing.assert_array_equal(distance[2], [3, 2, 1, 0, 0, 1, 2, 3, 4, 5])
    small = np.zeros((2, 6, 10))
    small[0, :, 4:] = 5 / 255  # 5 ab units: not an edge
    assert np.isinf(correlation_edge_distance(small)).all()


def test_latent_error_by_edge_distance_finds_a_colour_bleeding_across_an_edge() -> None:
    """A reading whose left colour bleeds 3 px into the right region errs only in the 0-4 px bin, by the jump."""
    size = 64
    target = np.zeros((1, 3, size, size))
    target[:, 0] = 0.5  # density 0.5 everywhere: every pixel counts
    target[:, 1] = 0.3
    target[:, 1, :, 32:] = 0.3 + 51 / 255  # a jumps by 51 ab units at column 32
    predicted = target.copy()
    predicted[:, 1, :, 32:35] = 0.3  # the left colour bleeds over columns 32-34
    rows = latent_error_by_edge_distance(predicted, target)
    assert [row["from_px"] for row in rows] == [0, 4, 8, 16, 32] and rows[-1]["to_px"] is None
    near = rows[0]
    assert near["pixels"] == size * 8  # columns 28-35
    assert near["mean_ab_error"] == pytest.approx(51 * 3 / 8, abs=0.01)  # 3 of its 8 columns wrong by 51
    assert all(row["mean_ab_error"] == 0 for row in rows[1:4]) and rows[4]["pixels"] == 0
    light = target.copy()
    light[:, 0] = 1.0  # no ink: nothing counted
    assert all(row["pixels"] == 0 and row["mean_ab_error"] is None for row in latent_error_by_edge_distance(predicted, light))


class _FixedAnswers:
    """A stand-in model that answers each of the given rasters with its given (3, S, S) map."""

    def __init__(self, rasters: np.ndarray, outputs: np.ndarray) -> None:
        self.answers = {np.asarray(r, np.float32).tobytes(): o for r, o in zip(rasters, outputs, strict=True)}

    def predict(self, rasters: np.ndarray) -> np.ndarray:
        return np.stack([self.answers[np.asarray(r[0], np.float32).tobytes()] for r in rasters]).astype(np.float32)


def test_network_output_decodes_to_lab() -> None:
    from synthesis.labmap import LabMap

    output = np.random.default_rng(0).random((3, 4, 5)).astype(np.float32)
    lab_map = LabMap.from_network(output)
    np.testing.assert_allclose(lab_map.L, 100 * output[0], atol=1e-4)
    np.testing.assert_allclose(lab_map.ab, 255 * output[1:].transpose(1, 2, 0) - 128, atol=1e-4)


# --- up-sampling without a lattice (issue 14) ---------------------------------------
def phase_locked_share(channel: np.ndarray, period: int) -> float:
    """Share of a (H, W) channel's variance in its mean over each phase modulo ``period`` (0 for a constant)."""
    h, w = (side // period * period for side in channel.shape)
    tiles = channel[:h, :w].reshape(h // period, period, w // period, period)
    variance = float(channel[:h, :w].var())
    return float(((tiles.mean(axis=(0, 2)) - channel[:h, :w].mean()) ** 2).mean() / variance) if variance > 0 else 0.0


@pytest.mark.parametrize("upsample", ["nearest", "bilinear"])
def test_resize_convolution_has_no_lattice_on_a_constant_input(upsample: str) -> None:
    """A fresh resize-convolution net maps a constant raster to a constant interior; transposed convolutions do not.

    512 px: the bottleneck is 8 x 8 cells, so the central 256 x 256 px lie beyond the reach of the zero padding.
    """
    torch.manual_seed(0)
    outputs = {}
    for kind in (upsample, "transposed"):
        net = DualBranchUNet(base_channels=4, max_channels=16, upsample=kind).eval()
        with torch.no_grad():
            outputs[kind] = net(torch.full((1, 1, 512, 512), 0.1))[0, :, 128:384, 128:384].numpy()
    assert np.ptp(outputs[upsample], axis=(1, 2)).max() < 1e-6
    locked = [phase_locked_share(channel.astype(np.float64), 64) for channel in outputs["transposed"]]
    assert np.ptp(outputs["transposed"], axis=(1, 2)).min() > 1e-5 and min(locked) > 0.9


@pytest.mark.parametrize(("height", "width", "bias"), [(5, 7, True), (1, 1, False), (8, 8, True)])
def test_fused_nearest_up_convolution_equals_upsample_then_convolution(height: int, width: int, bias: bool) -> None:
    torch.manual_seed(height)
    conv = torch.nn.Conv2d(3, 5, 3, 1, 1, bias=bias)
    x = torch.randn(2, 3, height, width)
    with torch.no_grad():
        expected = conv(torch.nn.functional.interpolate(x, scale_factor=2, mode="nearest"))
        assert torch.allclose(NearestUpConv(conv)(x), expected, atol=1e-5)
    with pytest.raises(ValueError, match="3x3"):
        NearestUpConv(torch.nn.Conv2d(3, 5, 5, 1, 2))


def test_fused_generator_computes_the_same_map() -> None:
    torch.manual_seed(1)
    generator = DualBranchUNet(base_channels=4, max_channels=16, upsample="nearest").eval()
    raster = torch.rand(1, 1, 128, 128) * 0.3
    with torch.no_grad():
        expected = generator(raster)
        fused = fuse_upsampling(generator)
        assert sum(isinstance(m, NearestUpConv) for m in fused.modules()) == 2 * 6  # every decoder level and head
        assert torch.allclose(fused(raster), expected, atol=1e-6)
    transposed = DualBranchUNet(base_channels=4, max_channels=16, upsample="transposed")
    assert not any(isinstance(m, NearestUpConv) for m in fuse_upsampling(transposed).modules())


def test_new_runs_use_resize_convolution_and_the_shipped_config_still_builds() -> None:
    """conf/model's default is resize-convolution, and the shipped model's recorded config builds its net (resize-convolution)."""
    from omegaconf import OmegaConf

    from export.runtime import OnnxModel

    assert compose_config("train", []).model.upsample == "nearest"
    recorded = OmegaConf.to_container(OmegaConf.load(ROOT / "patternshop_nn" / "assets" / "default.config.yaml").model)
    module = Pix2PixModule(**{key: value for key, value in recorded.items() if key != "_target_"})
    assert module.generator.upsample == "nearest"
    shipped = OnnxModel().metadata["generator"]["parameters"]
    assert sum(p.numel() for p in module.generator.parameters()) == shipped


def test_resize_convolution_exports_with_dynamic_sizes(tmp_path: Path) -> None:
    from patternshop_nn.onnx_export import export_onnx, max_abs_difference

    torch.manual_seed(0)
    net = DualBranchUNet(base_channels=4, max_channels=8, upsample="nearest").eval()
    props = export_onnx(net, tmp_path / "resize.onnx")
    assert props["generator"]["upsample"] == "nearest"
    assert props["generator"]["parameters"] == sum(p.numel() for p in net.parameters())  # the trained net's, not the fused graph's
    rasters = np.random.default_rng(0).random((1, 1, 192, 192), dtype=np.float32)
    assert max_abs_difference(net, tmp_path / "resize.onnx", rasters) <= 1e-4


def test_a_checkpoint_from_before_the_upsample_option_loads_as_transposed(tmp_path: Path) -> None:
    """The shipped model's checkpoint records no ``upsample``: it loads (strictly) into the transposed architecture."""
    from patternshop_nn.onnx_export import load_generator

    old = Pix2PixModule(base_channels=4, max_channels=8, upsample="transposed")
    hparams = {key: value for key, value in dict(old.hparams).items() if key != "upsample"}
    checkpoint = tmp_path / "old.ckpt"
    torch.save({"state_dict": old.state_dict(), "hyper_parameters": hparams, "pytorch-lightning_version": L.__version__}, checkpoint)
    generator = load_generator(checkpoint)
    assert generator.upsample == "transposed"
    assert all(torch.equal(a, b) for a, b in zip(generator.state_dict().values(), old.generator.state_dict().values(), strict=True))
