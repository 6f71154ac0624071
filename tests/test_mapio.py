"""Map I/O: LabMap conventions, CIELAB/ICCLAB TIFF, channel PNGs, sRGB images, previews.

Conventions under test are SPEC section 3 (see synthesis/mapio.py for the stored values).
"""

from __future__ import annotations

import os
from pathlib import Path

import colour
import numpy as np
import pytest
import tifffile
from PIL import Image

from synthesis import mapio
from synthesis.errors import MapFormatError, PatternshopError, PatternshopWarning
from synthesis.labmap import LabMap
from synthesis.mapio import (
    channel_paths,
    encode_lab,
    read_channels,
    read_map,
    write_channels,
    write_map,
    write_preview,
    write_tiff,
)

_D65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]

# Half a quantisation step per channel (L, a/b), plus a float32 rounding allowance.
_FLOAT32_SLACK = 2e-5
HALF_STEP = {
    8: (100.0 / 255.0 / 2.0, 0.5),
    16: (100.0 / 65535.0 / 2.0, 1.0 / 512.0),
}
# Channel PNGs hold fractions of 65535: L = 100 f, a/b = 255 f - 128.
HALF_STEP_CHANNELS = (100.0 / 65535.0 / 2.0, 255.0 / 65535.0 / 2.0)

# The SPEC's worked example: L=50, a=20, b=-30.
EXAMPLE = (50.0, 20.0, -30.0)


# --- helpers -------------------------------------------------------------------
def random_map(seed: int, height: int, width: int) -> LabMap:
    """A seeded random map covering the full L, a, b ranges, with the extremes in row 0."""
    rng = np.random.default_rng(seed)
    lab = np.empty((height, width, 3))
    lab[..., 0] = rng.uniform(0.0, 100.0, (height, width))
    lab[..., 1:] = rng.uniform(-128.0, 127.0, (height, width, 2))
    extremes = [(0, -128, -128), (100, 127, 127), (0, 127, -128), (100, -128, 127), (50, 0, 0)]
    n = min(width, len(extremes))
    lab[0, :n] = extremes[:n]
    return LabMap(lab)


def uniform_map(lab: tuple[float, float, float], height: int = 3, width: int = 5) -> LabMap:
    return LabMap(np.broadcast_to(np.asarray(lab, float), (height, width, 3)))


def assert_within_half_step(got: LabMap, want: LabMap, half_step: tuple[float, float]) -> None:
    assert got.lab.shape == want.lab.shape
    err = np.abs(got.lab.astype(np.float64) - want.lab.astype(np.float64))
    assert err[..., 0].max() <= half_step[0] + _FLOAT32_SLACK
    assert err[..., 1:].max() <= half_step[1] + _FLOAT32_SLACK


def srgb_to_lab(rgb8: np.ndarray) -> np.ndarray:
    """colour-science's sRGB (8-bit) -> XYZ -> Lab (D65), independent of LabMap."""
    xyz = colour.sRGB_to_XYZ(np.asarray(rgb8, np.float64) / 255.0)
    return colour.XYZ_to_Lab(xyz, _D65)


def read_srgb(path: Path) -> LabMap:
    """read_map on an sRGB image, which must warn about the conversion."""
    with pytest.warns(PatternshopWarning, match="sRGB"):
        return read_map(path)


def assert_no_stray_files(folder: Path, expected: set[str]) -> None:
    assert {p.name for p in folder.iterdir()} == expected


# --- LabMap ---------------------------------------------------------------------
@pytest.mark.parametrize("shape", [(4, 4), (4, 4, 4), (4, 4, 2), (0, 4, 3), (4, 0, 3), (2, 4, 4, 3)])
def test_labmap_rejects_bad_shapes(shape):
    with pytest.raises(MapFormatError, match="shape"):
        LabMap(np.zeros(shape))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_labmap_rejects_non_finite(bad):
    lab = np.zeros((2, 2, 3))
    lab[1, 0, 2] = bad
    with pytest.raises(MapFormatError):
        LabMap(lab)


def test_labmap_clips_into_range_and_is_immutable():
    source = np.array([[[-5.0, -300.0, 200.0], [150.0, 127.5, -128.5], [42.0, 1.5, -2.5]]])
    m = LabMap(source)
    assert m.lab.dtype == np.float32
    np.testing.assert_array_equal(m.lab, [[[0, -128, 127], [100, 127, -128], [42, 1.5, -2.5]]])
    source[0, 2, 0] = 7.0  # the map keeps its own copy
    assert m.L[0, 2] == 42.0
    with pytest.raises(ValueError):
        m.lab[0, 0, 0] = 1.0


def test_density_and_latent():
    m = LabMap(np.array([[[0.0, -128.0, 127.0], [100.0, 127.0, -128.0], [25.0, 0.0, 27.5]]]))
    np.testing.assert_allclose(m.density(), [[1.0, 0.0, 0.75]], atol=1e-6)
    np.testing.assert_allclose(m.latent(), [[[0, 1], [1, 0], [128 / 255, 155.5 / 255]]], atol=1e-6)
    # The 8-bit a/b grid and the 256 x 256 table coincide: integer a -> z = k / 255.
    ks = np.arange(256)
    grid = LabMap(np.stack([np.full(256, 50.0), ks - 128.0, 127.0 - ks], axis=-1)[None])
    np.testing.assert_allclose(grid.latent()[0, :, 0] * 255, ks, atol=1e-4)


def test_from_density_latent_inverts_density_and_latent():
    rng = np.random.default_rng(3)
    density, latent = rng.uniform(0, 1, (6, 9)), rng.uniform(0, 1, (6, 9, 2))
    m = LabMap.from_density_latent(density, latent)
    assert (m.height, m.width) == (6, 9)
    np.testing.assert_allclose(m.density(), density, atol=1e-5)
    np.testing.assert_allclose(m.latent(), latent, atol=1e-5)
    np.testing.assert_allclose(m.L, 100 * (1 - density), atol=1e-4)
    np.testing.assert_allclose(m.ab, 255 * latent - 128, atol=1e-4)
    # and the other way round
    again = LabMap.from_density_latent(m.density(), m.latent())
    np.testing.assert_allclose(again.lab, m.lab, atol=1e-4)


def test_from_density_latent_rejects_mismatched_shapes():
    with pytest.raises(MapFormatError):
        LabMap.from_density_latent(np.zeros((4, 5)), np.zeros((5, 4, 2)))
    with pytest.raises(MapFormatError):
        LabMap.from_density_latent(np.zeros((4, 5)), np.zeros((4, 5)))


@pytest.mark.parametrize(
    ("height", "width", "domain"),
    [(20, 30, (1.0, 2 / 3)), (30, 20, (2 / 3, 1.0)), (7, 7, (1.0, 1.0)), (1, 4, (1.0, 0.25))],
)
def test_domain_has_longer_side_one(height, width, domain):
    m = LabMap(np.zeros((height, width, 3)))
    assert (m.width, m.height) == (width, height)
    assert m.domain == pytest.approx(domain)


# --- CIELAB TIFF ---------------------------------------------------------------
@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize(("height", "width", "seed"), [(16, 16, 0), (7, 23, 1), (31, 5, 2)])
def test_tiff_round_trip_exact_to_quantisation(tmp_path, bits, height, width, seed):
    original = random_map(seed, height, width)
    first, second = tmp_path / "first.tif", tmp_path / "second.tiff"
    write_map(original, first, bits=bits)
    once = read_map(first)
    assert_within_half_step(once, original, HALF_STEP[bits])
    write_map(once, second, bits=bits)
    twice = read_map(second)
    np.testing.assert_array_equal(twice.lab, once.lab)
    np.testing.assert_array_equal(tifffile.imread(second), tifffile.imread(first))


@pytest.mark.parametrize("bits", [8, 16])
def test_tiff_extremes_survive(tmp_path, bits):
    corners = np.array([[[0, -128, -128], [100, 127, 127]], [[0, 127, -128], [100, -128, 127]]], float)
    write_tiff(LabMap(corners), tmp_path / "m.tif", bits=bits)
    np.testing.assert_array_equal(read_map(tmp_path / "m.tif").lab, corners)


@pytest.mark.parametrize(
    ("bits", "dtype", "signed", "want"),
    [(8, np.uint8, np.int8, (128, 20, -30)), (16, np.uint16, np.int16, (32768, 5120, -7680))],
)
def test_tiff_raw_encoding(tmp_path, bits, dtype, signed, want):
    path = tmp_path / "m.tif"
    write_tiff(uniform_map(EXAMPLE, 3, 5), path, bits=bits)
    with tifffile.TiffFile(path) as tif:
        page = tif.pages.first
        assert int(page.photometric) == 8  # CIELAB
        assert page.bitspersample == bits
        assert page.shape == (3, 5, 3)
        raw = page.asarray()
    assert raw.dtype == dtype
    assert raw[..., 0].max() == raw[..., 0].min() == want[0]
    np.testing.assert_array_equal(raw[..., 1:].view(signed)[0, 0], want[1:])
    np.testing.assert_array_equal(encode_lab(uniform_map(EXAMPLE, 3, 5), bits), raw)


def test_encode_lab_rejects_other_depths(tmp_path):
    with pytest.raises(MapFormatError):
        encode_lab(uniform_map(EXAMPLE), 12)
    with pytest.raises(MapFormatError):
        write_map(uniform_map(EXAMPLE), tmp_path / "m.tif", bits=32)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("raw", "want"),
    [
        # 8-bit ICCLAB: a, b unsigned with a +128 offset.
        (
            np.array([[[128, 148, 98], [255, 0, 255], [0, 128, 128]]], np.uint8),
            [[[50.19608, 20, -30], [100, -128, 127], [0, 0, 0]]],
        ),
        # 16-bit ICCLAB: a = v * 255 / 65535 - 128.
        (
            np.array([[[32768, 65535, 0], [0, 37888, 25088], [65535, 32896, 32896]]], np.uint16),
            [[[50.000763, 127, -128], [0, 37888 * 255 / 65535 - 128, 25088 * 255 / 65535 - 128], [100, 0, 0]]],
        ),
    ],
)
def test_icclab_tiff_is_decoded(tmp_path, raw, want):
    path = tmp_path / "icc.tif"
    tifffile.imwrite(path, raw, photometric=9)
    np.testing.assert_allclose(read_map(path).lab, want, atol=1e-4)


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize(
    "options",
    [
        pytest.param({"planarconfig": "separate"}, id="planar-separate"),
        pytest.param({"compression": "lzw"}, id="lzw"),
        pytest.param({"compression": "zlib", "predictor": True}, id="deflate-predictor"),
        pytest.param({"byteorder": ">"}, id="big-endian"),
        pytest.param({"tile": (16, 16)}, id="tiled"),
        pytest.param({"extrasamples": [2], "planarconfig": "contig"}, id="alpha"),
    ],
)
def test_cielab_tiff_variants_are_read(tmp_path, bits, options):
    original = random_map(4, 20, 33)
    raw = encode_lab(original, bits)
    if options.get("planarconfig") == "separate":
        raw = np.moveaxis(raw, -1, 0)
    if "extrasamples" in options:
        raw = np.concatenate([raw, np.full(raw.shape[:2] + (1,), 7, raw.dtype)], axis=-1)
    path = tmp_path / "variant.tif"
    tifffile.imwrite(path, raw, photometric=8, **options)
    if "extrasamples" in options:
        with tifffile.TiffFile(path) as tif:
            assert tif.pages.first.shape == (20, 33, 4)
        with pytest.warns(PatternshopWarning, match="alpha"):  # read, and said to be ignored
            assert_within_half_step(read_map(path), original, HALF_STEP[bits])
    else:
        assert_within_half_step(read_map(path), original, HALF_STEP[bits])


# --- channel PNGs ------------------------------------------------------------------
def test_channel_paths_names():
    want = tuple(Path("d") / f"face.{c}.png" for c in "Lab")
    for name in ("face.png", "face.L.png", "face.a.png", "face.b.png", "face"):
        assert channel_paths(Path("d") / name) == want
    assert channel_paths("d/my.face.L.png") == tuple(Path("d") / f"my.face.{c}.png" for c in "Lab")


def test_channel_png_round_trip(tmp_path):
    original = random_map(5, 13, 29)
    written = write_channels(original, tmp_path / "face.png")
    assert written == channel_paths(tmp_path / "face")
    for path in written:
        with Image.open(path) as image:
            assert image.mode.startswith("I")  # 16-bit greyscale
            assert image.size == (29, 13)
    once = read_map(tmp_path / "face.L.png")
    assert_within_half_step(once, original, HALF_STEP_CHANNELS)
    for name in ("face.a.png", "face.b.png"):
        np.testing.assert_array_equal(read_map(tmp_path / name).lab, once.lab)
    for name in ("face.png", "face", "face.b.png"):
        np.testing.assert_array_equal(read_channels(tmp_path / name).lab, once.lab)
    # second cycle, through write_map with a channel name, is bit-exact
    write_map(once, tmp_path / "again.a.png")
    np.testing.assert_array_equal(read_map(tmp_path / "again.b.png").lab, once.lab)
    for c in "Lab":
        with Image.open(tmp_path / f"face.{c}.png") as a, Image.open(tmp_path / f"again.{c}.png") as b:
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_channel_png_stored_values(tmp_path):
    write_channels(LabMap(np.array([[[50.0, 20.0, -30.0], [100.0, -128.0, 127.0]]])), tmp_path / "m")
    values = [np.asarray(Image.open(tmp_path / f"m.{c}.png")).astype(int) for c in "Lab"]
    np.testing.assert_array_equal(values[0], [[32768, 65535]])
    np.testing.assert_array_equal(values[1], [[round(148 / 255 * 65535), 0]])
    np.testing.assert_array_equal(values[2], [[round(98 / 255 * 65535), 65535]])


def save_channel_pngs(folder: Path, stem: str, images: dict[str, np.ndarray], mode: str = "L") -> None:
    for c, values in images.items():
        Image.fromarray(np.asarray(values, np.uint8), mode=mode).save(folder / f"{stem}.{c}.png")


def test_8bit_channel_pngs_are_read(tmp_path):
    v = np.arange(0, 256, 17).reshape(4, 4)
    save_channel_pngs(tmp_path, "g", {"L": v, "a": v, "b": 255 - v})
    m = read_map(tmp_path / "g.L.png")
    np.testing.assert_allclose(m.L, 100 * v / 255, atol=1e-4)
    np.testing.assert_allclose(m.ab[..., 0], v - 128.0, atol=1e-4)
    np.testing.assert_allclose(m.ab[..., 1], 127.0 - v, atol=1e-4)


def test_grey_rgb_channel_png_is_accepted_coloured_is_rejected(tmp_path):
    v = np.full((3, 4), 200, np.uint8)
    save_channel_pngs(tmp_path, "m", {"L": v, "a": v})
    Image.fromarray(np.stack([v, v, v], axis=-1), mode="RGB").save(tmp_path / "m.b.png")
    np.testing.assert_allclose(read_map(tmp_path / "m.L.png").ab[..., 1], 72.0)
    rgb = np.stack([v, v, v - 1], axis=-1)
    Image.fromarray(rgb, mode="RGB").save(tmp_path / "m.b.png")
    with pytest.raises(MapFormatError, match=r"m\.b\.png.*colour"):
        read_map(tmp_path / "m.L.png")


def test_missing_channel_sibling(tmp_path):
    write_channels(uniform_map(EXAMPLE), tmp_path / "m")
    (tmp_path / "m.a.png").unlink()
    with pytest.raises(MapFormatError, match=r"m\.a\.png"):
        read_map(tmp_path / "m.L.png")
    with pytest.raises(MapFormatError, match=r"m\.a\.png"):
        read_channels(tmp_path / "m")


def test_channels_of_different_sizes(tmp_path):
    save_channel_pngs(tmp_path, "m", {"L": np.zeros((4, 5)), "a": np.zeros((4, 5)), "b": np.zeros((5, 4))})
    with pytest.raises(MapFormatError, match="size"):
        read_map(tmp_path / "m.b.png")


# --- sRGB images ----------------------------------------------------------------------
PATCHES = np.array(
    [[200, 100, 50], [10, 200, 30], [30, 40, 220], [128, 128, 128], [255, 255, 255], [0, 0, 0]], np.uint8
)


def patch_image(patches: np.ndarray, size: int) -> np.ndarray:
    """A 1-row strip of flat size x size patches."""
    return np.repeat(np.repeat(patches[None], size, axis=0), size, axis=1)


def test_srgb_png_is_converted_with_warning(tmp_path):
    path = tmp_path / "s.png"
    Image.fromarray(patch_image(PATCHES, 2)).save(path)
    m = read_srgb(path)
    assert (m.height, m.width) == (2, 2 * len(PATCHES))
    np.testing.assert_allclose(m.lab[0, ::2], srgb_to_lab(PATCHES), atol=1e-3)
    np.testing.assert_allclose(m.lab[0, 0], (53.626, 36.313, 45.384), atol=2e-3)
    np.testing.assert_allclose(LabMap.from_srgb(PATCHES[None] / 255.0).lab[0], srgb_to_lab(PATCHES), atol=1e-3)


def test_srgb_png_with_alpha_and_palette(tmp_path):
    rgba = np.concatenate([patch_image(PATCHES, 1), np.full((1, len(PATCHES), 1), 90, np.uint8)], axis=-1)
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "a.png")
    palette = Image.fromarray(patch_image(PATCHES, 1)).convert("P", palette=Image.Palette.ADAPTIVE, colors=16)
    palette.save(tmp_path / "p.png")
    with pytest.warns(PatternshopWarning, match="alpha channel is ignored"):  # besides read_srgb's sRGB warning
        np.testing.assert_allclose(read_srgb(tmp_path / "a.png").lab[0], srgb_to_lab(PATCHES), atol=1e-3)
    np.testing.assert_allclose(read_srgb(tmp_path / "p.png").lab[0], srgb_to_lab(PATCHES), atol=1e-3)


def test_greyscale_png_has_no_chroma(tmp_path):
    v = np.arange(0, 256, 5, dtype=np.uint8).reshape(1, -1)
    Image.fromarray(v, mode="L").save(tmp_path / "g.png")
    m = read_srgb(tmp_path / "g.png")
    np.testing.assert_allclose(m.ab, 0.0, atol=0.05)
    np.testing.assert_allclose(m.L, srgb_to_lab(np.repeat(v[..., None], 3, axis=-1))[..., 0], atol=1e-3)
    # 16-bit greyscale PNG too
    Image.fromarray(v.astype(np.uint16) * 257).save(tmp_path / "g16.png")
    np.testing.assert_allclose(read_srgb(tmp_path / "g16.png").lab, m.lab, atol=1e-3)


@pytest.mark.parametrize("suffix", [".jpg", ".jpeg"])
def test_jpeg_is_converted_with_warning(tmp_path, suffix):
    path = tmp_path / f"s{suffix}"
    Image.fromarray(patch_image(PATCHES, 16)).save(path, quality=95)
    with pytest.warns(PatternshopWarning, match="JPEG"):
        m = read_map(path)
    centres = m.lab[8, 8::16]
    # JPEG is lossy: flat 16 x 16 patches come back within a few units at their centres.
    np.testing.assert_allclose(centres, srgb_to_lab(PATCHES), atol=3.0)


def test_rgb_tiff_is_converted_with_warning(tmp_path):
    tifffile.imwrite(tmp_path / "rgb.tif", patch_image(PATCHES, 1), photometric="rgb")
    np.testing.assert_allclose(read_srgb(tmp_path / "rgb.tif").lab[0], srgb_to_lab(PATCHES), atol=1e-3)


# --- previews --------------------------------------------------------------------------
@pytest.mark.parametrize("scale", [1, 3])
def test_write_preview(tmp_path, scale):
    m = random_map(6, 9, 14)
    path = tmp_path / "preview.png"
    write_preview(m, path, scale=scale)
    with Image.open(path) as image:
        assert image.mode == "RGB"
        assert image.size == (14 * scale, 9 * scale)
        pixels = np.asarray(image).astype(np.float64)
    want = np.repeat(np.repeat(m.to_srgb() * 255.0, scale, axis=0), scale, axis=1)
    assert np.abs(pixels - want).max() <= 1.0
    assert_no_stray_files(tmp_path, {"preview.png"})


def test_write_preview_rejects_bad_scale(tmp_path):
    with pytest.raises(PatternshopError):
        write_preview(uniform_map(EXAMPLE), tmp_path / "p.png", scale=0)
    assert not (tmp_path / "p.png").exists()


# --- errors ----------------------------------------------------------------------------
def test_missing_file(tmp_path):
    for name in ("nope.tif", "nope.png", "nope.jpg", "nope.L.png"):
        with pytest.raises(MapFormatError, match="nope"):
            read_map(tmp_path / name)


def test_unsupported_suffix(tmp_path):
    path = tmp_path / "map.bmp"
    Image.new("RGB", (2, 2)).save(path)
    with pytest.raises(MapFormatError, match=r"map\.bmp.*unsupported"):
        read_map(path)


def test_corrupt_tiff(tmp_path):
    path = tmp_path / "junk.tif"
    path.write_bytes(np.random.default_rng(7).bytes(600))
    with pytest.raises(MapFormatError, match=r"junk\.tif"):
        read_map(path)
    (tmp_path / "empty.tiff").write_bytes(b"")
    with pytest.raises(MapFormatError, match=r"empty\.tiff"):
        read_map(tmp_path / "empty.tiff")


def test_corrupt_png_and_jpeg(tmp_path):
    (tmp_path / "junk.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 20)
    (tmp_path / "junk.jpg").write_bytes(b"\xff\xd8\xff" + b"garbage" * 20)
    for name in ("junk.png", "junk.jpg"):
        with pytest.raises(MapFormatError, match=name.replace(".", r"\.")):
            read_map(tmp_path / name)


def test_truncated_compressed_tiff(tmp_path):
    path = tmp_path / "cut.tif"
    write_tiff(random_map(8, 64, 64), path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 64])
    with pytest.raises(MapFormatError, match=r"cut\.tif"):
        read_map(path)


def test_truncated_uncompressed_tiff(tmp_path):
    path = tmp_path / "cut.tif"
    tifffile.imwrite(path, encode_lab(random_map(8, 64, 64), 16), photometric=8)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(MapFormatError, match=r"cut\.tif"):
        read_map(path)


@pytest.mark.parametrize(
    ("data", "options", "match"),
    [
        (np.zeros((2, 2, 4), np.uint8), {"photometric": "separated"}, "photometric"),
        (np.zeros((2, 2, 3), np.uint8), {"photometric": "ycbcr", "subsampling": (1, 1)}, "photometric"),
        (np.zeros((2, 2, 3), np.float32), {"photometric": 8}, "32-bit"),
    ],
    ids=["cmyk", "ycbcr", "float-lab"],
)
def test_unsupported_tiff_kinds(tmp_path, data, options, match):
    path = tmp_path / "odd.tif"
    tifffile.imwrite(path, data, **options)
    with pytest.raises(MapFormatError, match=rf"odd\.tif.*{match}"):
        read_map(path)


@pytest.mark.parametrize("name", ["map.png", "map.jpg", "map.bmp", "map"])
def test_write_map_refuses_lossy_or_unknown_targets(tmp_path, name):
    with pytest.raises(MapFormatError, match=name.replace(".", r"\.")):
        write_map(uniform_map(EXAMPLE), tmp_path / name)
    assert not list(tmp_path.iterdir())


# --- atomic writes -----------------------------------------------------------------------
class _Boom(RuntimeError):
    pass


def failing_writer(calls_before_failure: int, real_write):
    """A writer that behaves like ``real_write`` for some calls, then writes junk bytes and raises."""
    calls = {"n": 0}

    def write(target, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] > calls_before_failure:
            Path(target).write_bytes(b"half a file")
            raise _Boom("disk full")
        return real_write(target, *args, **kwargs)

    return write


@pytest.mark.parametrize("existing", [False, True])
def test_failed_tiff_write_leaves_nothing_behind(tmp_path, monkeypatch, existing):
    target = tmp_path / "m.tif"
    if existing:
        write_tiff(uniform_map(EXAMPLE), target, bits=8)
    before = target.read_bytes() if existing else None
    monkeypatch.setattr(mapio.tifffile, "imwrite", failing_writer(0, tifffile.imwrite))
    with pytest.raises(_Boom):
        write_map(random_map(9, 8, 8), target)
    assert_no_stray_files(tmp_path, {"m.tif"} if existing else set())
    if existing:
        assert target.read_bytes() == before


@pytest.mark.parametrize("existing", [False, True])
def test_failed_channel_write_leaves_nothing_behind(tmp_path, monkeypatch, existing):
    names = {f"m.{c}.png" for c in "Lab"}
    if existing:
        write_channels(uniform_map(EXAMPLE), tmp_path / "m")
    before = {n: (tmp_path / n).read_bytes() for n in names} if existing else {}
    real_save = Image.Image.save
    # the first two channels are written, the third fails half-way
    writer = failing_writer(2, lambda fp, image, *a, **k: real_save(image, fp, *a, **k))
    monkeypatch.setattr(Image.Image, "save", lambda self, fp, *a, **k: writer(fp, self, *a, **k))
    with pytest.raises(_Boom):
        write_channels(random_map(9, 8, 8), tmp_path / "m.L.png")
    monkeypatch.undo()
    assert_no_stray_files(tmp_path, names if existing else set())
    assert {n: (tmp_path / n).read_bytes() for n in before} == before


def test_failed_preview_write_leaves_nothing_behind(tmp_path, monkeypatch):
    writer = failing_writer(0, None)
    monkeypatch.setattr(Image.Image, "save", lambda self, fp, *a, **k: writer(fp))
    with pytest.raises(_Boom):
        write_preview(uniform_map(EXAMPLE), tmp_path / "p.png")
    monkeypatch.undo()
    assert_no_stray_files(tmp_path, set())


def test_written_files_are_ordinary_files(tmp_path):
    write_tiff(uniform_map(EXAMPLE), tmp_path / "m.tif")
    mode = os.stat(tmp_path / "m.tif").st_mode & 0o777
    umask = os.umask(0)
    os.umask(umask)
    assert mode == 0o666 & ~umask
