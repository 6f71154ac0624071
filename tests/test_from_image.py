"""``from-image`` and :mod:`synthesis.photo`: photos -> maps with L = 100 x linear luminance."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli as run
from PIL import Image

from synthesis.errors import PatternshopError, PatternshopWarning
from synthesis.mapio import read_map
from synthesis.palette import load_palette
from synthesis.labmap import srgb_to_linear
from synthesis.photo import parse_correlation, photo_to_map

MID_GREY = 119  # sRGB value of CIELAB L* = 50: linear Y = 0.1845
Y_MID = float(srgb_to_linear(MID_GREY / 255))
BLUE = (0.0, 0.0)  # an arbitrary base correlation for library calls


def save(tmp_path: Path, name: str, pixels: np.ndarray | Image.Image, **kwargs) -> Path:
    path = tmp_path / name
    image = pixels if isinstance(pixels, Image.Image) else Image.fromarray(pixels)
    image.save(path, **kwargs)
    return path


def grey(tmp_path: Path, values, name: str = "photo.png") -> Path:
    return save(tmp_path, name, np.asarray(values, np.uint8))


def test_mid_grey_is_linear_luminance_not_lstar(tmp_path):
    """L* = 50 must become L = 18.4 (what the dots print), not 50; white 100, black 0."""
    assert Y_MID == pytest.approx(0.1845, abs=2e-4)
    lab_map = photo_to_map(grey(tmp_path, [[MID_GREY, 255, 0]]), BLUE)
    np.testing.assert_allclose(lab_map.L[0], [18.45, 100.0, 0.0], atol=0.05)


def test_sixteen_bit_grey_and_rgb_palette_rgba(tmp_path):
    sixteen = save(tmp_path, "g16.png", np.array([[0, 30563, 65535]], np.uint16))
    assert Image.open(sixteen).mode.startswith("I")
    np.testing.assert_allclose(photo_to_map(sixteen, BLUE).L[0], [0.0, 18.42, 100.0], atol=0.02)

    rgb = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255]]], np.uint8)
    expected = [21.26, 71.52, 7.22]  # 100 x the Rec. 709 weights
    np.testing.assert_allclose(photo_to_map(save(tmp_path, "rgb.png", rgb), BLUE).L[0], expected, atol=0.01)
    palette = Image.fromarray(rgb).quantize(colors=3, method=Image.Quantize.MAXCOVERAGE)
    assert palette.mode == "P"
    np.testing.assert_allclose(photo_to_map(save(tmp_path, "p.png", palette), BLUE).L[0], expected, atol=0.01)

    rgba = np.array([[[0, 0, 0, 255], [0, 0, 0, 0], [0, 0, 0, 128]]], np.uint8)
    path = save(tmp_path, "rgba.png", rgba)
    np.testing.assert_allclose(photo_to_map(path, BLUE).L[0], [0.0, 100.0, 100 - 100 * 128 / 255], atol=0.01)
    np.testing.assert_allclose(photo_to_map(path, BLUE, invert=True).L[0], [100.0, 100.0, 100.0], atol=0.01)


def test_exif_orientation_is_applied(tmp_path):
    pixels = np.array([[0, 255, 255], [255, 255, 255]], np.uint8)  # 3 wide, 2 high, black top-left
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 clockwise to view"
    path = save(tmp_path, "rot.jpg", Image.fromarray(pixels), exif=exif, quality=100)
    lab_map = photo_to_map(path, BLUE)
    assert (lab_map.height, lab_map.width) == (3, 2)
    assert lab_map.L[0, 1] < 30 and lab_map.L[0, 0] > 70  # black went to the top-right


def test_invert_gamma_levels(tmp_path):
    path = grey(tmp_path, [[MID_GREY, 255, 0, 60]])
    np.testing.assert_allclose(photo_to_map(path, BLUE, invert=True).L[0, :3], [100 - 18.45, 0.0, 100.0], atol=0.05)
    np.testing.assert_allclose(photo_to_map(path, BLUE, gamma=2.0).L[0, 0], 100 * Y_MID**2, atol=0.01)
    np.testing.assert_allclose(photo_to_map(path, BLUE, gamma=0.5).L[0, 0], 100 * Y_MID**0.5, atol=0.01)
    white_at_mid = photo_to_map(path, BLUE, levels=(0, MID_GREY)).L[0]
    np.testing.assert_allclose(white_at_mid[:3], [100.0, 100.0, 0.0], atol=0.01)
    assert white_at_mid[3] == pytest.approx(100 * srgb_to_linear(60 / MID_GREY), abs=0.01)  # an editor's Levels
    np.testing.assert_allclose(photo_to_map(path, BLUE, levels=(MID_GREY, 255)).L[0, [0, 3]], [0.0, 0.0], atol=0.01)


def test_large_photos_are_downsampled_in_linear_light(tmp_path):
    checker = np.indices((64, 128)).sum(axis=0) % 2 * 255  # black/white pixels: half the light
    path = grey(tmp_path, checker)
    with pytest.warns(PatternshopWarning, match="128x64 px downsampled to 32x16"):
        lab_map = photo_to_map(path, BLUE, max_side=32)
    assert (lab_map.width, lab_map.height) == (32, 16) and lab_map.domain == (1.0, 0.5)
    np.testing.assert_allclose(lab_map.L, 50.0, atol=0.01)  # averaging sRGB values would give 21.4
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert photo_to_map(path, BLUE).width == 128


def test_correlation_from_labels_and_mask(tmp_path):
    presets = load_palette().preset_ab()
    photo = grey(tmp_path, np.full((2, 3), 128))
    labels = grey(tmp_path, [[0, 0, 255], [7, 255, 0]], "labels.png")
    lab_map = photo_to_map(photo, presets["white"], labels=labels, label_ab={0: presets["blue"], 255: presets["red"]})
    expected = [[presets["blue"], presets["blue"], presets["red"]], [presets["white"], presets["red"], presets["blue"]]]
    np.testing.assert_allclose(lab_map.ab, expected)

    colour = np.zeros((2, 3, 3), np.uint8)
    colour[0, 1] = (255, 0, 0)
    colour_labels = save(tmp_path, "colour.png", colour)
    lab_map = photo_to_map(photo, (0, 0), labels=colour_labels, label_ab={(255, 0, 0): (10, -20), 0: (30, 40)})
    np.testing.assert_allclose(lab_map.ab[0, :2], [[30, 40], [10, -20]])

    indexed = Image.fromarray(np.array([[0, 1, 2], [2, 1, 0]], np.uint8), mode="P")
    indexed.putpalette([0, 0, 0, 255, 0, 0, 0, 255, 0])
    path = save(tmp_path, "indexed.png", indexed)
    lab_map = photo_to_map(photo, (0, 0), labels=path, label_ab={2: (5, 5), (255, 0, 0): (-5, -5)})
    np.testing.assert_allclose(lab_map.ab[..., 0], [[0, -5, 5], [5, -5, 0]])

    halves = np.zeros((40, 60), np.uint16)
    halves[:, 30:] = 1000  # a 16-bit label image, downsampled with the photo
    wide = grey(tmp_path, np.full((40, 60), 128), "wide.png")
    with pytest.warns(PatternshopWarning):
        lab_map = photo_to_map(wide, (0, 0), labels=save(tmp_path, "l16.png", halves), label_ab={1000: (50, 50)}, max_side=6)
    np.testing.assert_array_equal(lab_map.ab[..., 0], np.tile([0, 0, 0, 50, 50, 50], (4, 1)))

    mask = grey(tmp_path, [[255, 0, 255], [0, 255, 0]], "mask.png")
    lab_map = photo_to_map(photo, (-20, 40), mask=mask, mask_ab=(60, -80))
    np.testing.assert_allclose(lab_map.ab[0], [[60, -80], [-20, 40], [60, -80]])


def test_parse_correlation():
    presets = {"blue": (-2.0, -128.0)}
    assert parse_correlation("blue", presets) == (-2.0, -128.0)
    assert parse_correlation("-20.5, 40", presets) == (-20.5, 40.0)
    for bad in ("purple", "1,2,3", "200,0", "nan,0"):
        with pytest.raises(PatternshopError):
            parse_correlation(bad, presets)


def test_cli_writes_a_map_that_reads_back(tmp_path, capsys):
    photo = grey(tmp_path, np.tile(np.array([MID_GREY, 255, 0, 30], np.uint8), (3, 2)))
    output, preview = tmp_path / "map.tif", tmp_path / "preview.png"
    status, _, err = run(["from-image", str(photo), str(output), "--preview", str(preview), "--preset", "red"], capsys)
    assert status == 0, err
    lab_map = read_map(output)
    assert (lab_map.height, lab_map.width) == (3, 8)
    np.testing.assert_allclose(lab_map.L[0, :3], [18.45, 100.0, 0.0], atol=0.05)
    np.testing.assert_allclose(lab_map.ab, np.broadcast_to(load_palette().preset_ab()["red"], (3, 8, 2)), atol=0.01)
    assert Image.open(preview).size == (8, 3)
    assert "mean density" in err

    channels = tmp_path / "map.L.png"
    argv = ["from-image", str(photo), str(channels), "--ab", "10", "-20", "--gamma", "2"]
    assert run(argv, capsys)[0] == 0
    np.testing.assert_allclose(read_map(channels).L[0, 0], 100 * Y_MID**2, atol=0.01)
    np.testing.assert_allclose(read_map(channels).ab[0, 0], [10, -20], atol=0.01)


def test_cli_default_is_blue_and_labels(tmp_path, capsys):
    presets = load_palette().preset_ab()
    photo = grey(tmp_path, np.full((2, 2), 200))
    labels = grey(tmp_path, [[0, 255], [255, 0]], "labels.png")
    output = tmp_path / "map.tif"
    argv = ["from-image", str(photo), str(output), "--labels", str(labels), "--label", "255=green", "--label", "0=30,-40"]
    status, _, err = run(argv, capsys)
    assert status == 0, err
    np.testing.assert_allclose(read_map(output).ab[0], [[30, -40], presets["green"]], atol=0.01)
    assert run(["from-image", str(photo), str(output)], capsys)[0] == 0
    np.testing.assert_allclose(read_map(output).ab[1, 1], presets["blue"], atol=0.01)
    mask = grey(tmp_path, [[255, 0], [0, 0]], "mask.png")
    assert run(["from-image", str(photo), str(output), "--mask", str(mask), "--mask-preset", "red"], capsys)[0] == 0
    np.testing.assert_allclose(read_map(output).ab[0], [presets["red"], presets["blue"]], atol=0.01)


BAD_INPUTS = {
    "not-an-image": (["{text}", "{out}"], "not a readable image"),
    "missing-photo": (["{tmp}/nothing.png", "{out}"], "no such file"),
    "unknown-preset": (["{photo}", "{out}", "--preset", "purple"], "'purple' is neither a preset"),
    "labels-size": (["{photo}", "{out}", "--labels", "{small}", "--label", "0=blue"], "2x2 px, the photo 4x3 px"),
    "mask-size": (["{photo}", "{out}", "--mask", "{small}", "--mask-preset", "red"], "2x2 px, the photo 4x3 px"),
    "label-not-found": (["{photo}", "{out}", "--labels", "{labels}", "--label", "9=blue"], "no pixel has label 9 (labels found: 0, 255)"),
    "label-syntax": (["{photo}", "{out}", "--labels", "{labels}", "--label", "0:blue"], "write KEY=CORRELATION"),
    "label-key": (["{photo}", "{out}", "--labels", "{labels}", "--label", "red=blue"], "give a grey value"),
    "label-without-labels": (["{photo}", "{out}", "--label", "0=blue"], "--label needs --labels"),
    "labels-without-label": (["{photo}", "{out}", "--labels", "{labels}"], "at least one --label"),
    "mask-without-colour": (["{photo}", "{out}", "--mask", "{labels}"], "go together"),
    "levels": (["{photo}", "{out}", "--levels", "200", "100"], "0 <= black < white <= 255"),
    "gamma": (["{photo}", "{out}", "--gamma", "0"], "gamma must be"),
    "gamma-nan": (["{photo}", "{out}", "--gamma", "nan"], "gamma must be"),
    "ab-range": (["{photo}", "{out}", "--ab", "0", "300"], "a, b must be finite"),
    "max-side": (["{photo}", "{out}", "--max-side", "0"], "max_side must be"),
    "srgb-output": (["{photo}", "{tmp}/map.png"], "an sRGB .png is only a preview"),
    "output-folder": (["{photo}", "{tmp}/nodir/map.tif"], "does not exist"),
    "preview-folder": (["{photo}", "{out}", "--preview", "{tmp}/nodir/p.png"], "does not exist"),
    "overwrite-photo": (["{photo_tif}", "{photo_tif}"], "would overwrite the input"),
    "float-image": (["{float_tif}", "{out}"], "floating-point images are not supported"),
    "lab-image": (["{lab_tif}", "{out}"], "a CIELAB image (a map?) is not a photo"),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_inputs_one_line_exit_2_no_output(case, tmp_path, capsys):
    files = {
        "photo": grey(tmp_path, np.full((3, 4), 100)),
        "photo_tif": save(tmp_path, "photo.tif", np.full((3, 4), 100, np.uint8)),
        "small": grey(tmp_path, np.zeros((2, 2)), "small.png"),
        "labels": grey(tmp_path, [[0, 0, 255, 255]] * 3, "labels.png"),
        "float_tif": save(tmp_path, "float.tif", np.zeros((3, 4), np.float32)),
        "lab_tif": save(tmp_path, "lab.tif", Image.fromarray(np.zeros((3, 4, 3), np.uint8), mode="LAB")),
        "text": tmp_path / "photo.jpg",
    }
    files["text"].write_text("not an image\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    argv, expected = BAD_INPUTS[case]
    argv = [a.format(tmp=tmp_path, out=tmp_path / "out.tif", **files) for a in argv]
    status, _, err = run(["from-image", *argv], capsys)
    assert status == 2, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert expected in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
