"""Perceptual features: rasteriser, extractors (random CNN and VGG-16 from a local file), invariances."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from synthesis.errors import PatternshopError
from synthesis.features import FEATURE_SIZE, FeatureExtractor, VGG16Blocks, splat_raster
from synthesis.generators import generate


def test_splat_raster_places_a_unit_peak_where_the_point_is():
    centre = np.array([[16.5, 48.5]]) / 64  # the centre of pixel (row 48, column 16)
    raster = splat_raster(centre, (64, 64), sigma=0.02, pixels_per_unit=64, periodic=False)
    assert np.unravel_index(np.argmax(raster), raster.shape) == (48, 16)  # y down
    assert raster.max() == pytest.approx(1.0, abs=1e-6)
    wrapped = splat_raster(np.array([[0.999, 0.5]]), (64, 64), sigma=0.02, pixels_per_unit=64, periodic=True)
    assert wrapped[32, 0] > 0.5  # the splat wraps around the torus


def test_random_cnn_features_are_deterministic_and_discriminate():
    extractor = FeatureExtractor()
    white = [extractor(generate("white", 1024, seed=s), periodic=True) for s in (1, 2)]
    red = extractor(generate("red", 1024, seed=1), periodic=True)
    assert white[0].shape == (FEATURE_SIZE,)
    np.testing.assert_array_equal(white[0], FeatureExtractor()(generate("white", 1024, seed=1), periodic=True))
    within = np.abs(white[0] - white[1]).sum()
    assert np.abs(white[0] - red).sum() > 3 * within


def test_features_do_not_depend_on_density():
    """The same pattern at 4x the point count (a 2x2 tiling, scaled) gives nearly the same features."""
    extractor = FeatureExtractor()
    points = generate("blue", 1024, seed=3)
    tiled = np.concatenate([(points + [i, j]) / 2 for i in range(2) for j in range(2)])
    single, dense = extractor(points, periodic=True), extractor(tiled, periodic=True)
    other = extractor(generate("red", 1024, seed=3), periodic=True)
    assert np.abs(single - dense).sum() < 0.2 * np.abs(single - other).sum()


def torchvision_style_weights(path):
    """A stand-in for torchvision's vgg16 weights: random tensors under the same keys and shapes."""
    generator = torch.Generator().manual_seed(0)
    shapes = {0: (64, 3), 2: (64, 64), 5: (128, 64), 7: (128, 128)}
    state = {}
    for index, (out_channels, in_channels) in shapes.items():
        state[f"features.{index}.weight"] = torch.randn(out_channels, in_channels, 3, 3, generator=generator) * 0.1
        state[f"features.{index}.bias"] = torch.zeros(out_channels)
    state["classifier.0.weight"] = torch.zeros(4, 4)  # other keys are ignored
    torch.save(state, path)
    return state


def test_vgg16_loads_torchvision_format_weights(tmp_path):
    path = tmp_path / "vgg16.pth"
    state = torchvision_style_weights(path)
    network = VGG16Blocks(path)
    torch.testing.assert_close(network.convs[2].weight, state["features.5.weight"])
    pool1, pool2 = network(torch.rand(1, 1, 64, 64))
    assert pool1.shape == (1, 64, 32, 32) and pool2.shape == (1, 128, 16, 16)
    features = FeatureExtractor("vgg16", weights=str(path))(generate("blue", 1024, seed=0), periodic=True)
    assert features.shape == (FEATURE_SIZE,) and np.all(np.isfinite(features))


def test_vgg16_weight_errors_are_clear(tmp_path):
    with pytest.raises(PatternshopError, match="not found"):
        VGG16Blocks(tmp_path / "missing.pth")
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(PatternshopError, match="not a readable PyTorch weights file"):
        VGG16Blocks(junk)
    wrong = tmp_path / "wrong.pth"
    torch.save({"features.0.weight": torch.zeros(2, 2)}, wrong)
    with pytest.raises(PatternshopError, match="not VGG-16 weights"):
        VGG16Blocks(wrong)
    with pytest.raises(PatternshopError, match="needs a local weights file"):
        FeatureExtractor("vgg16")
    with pytest.raises(PatternshopError, match="unknown feature extractor"):
        FeatureExtractor("resnet")
