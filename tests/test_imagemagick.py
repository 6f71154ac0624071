"""Interoperability of our CIELAB TIFF maps with ImageMagick (IM).

Skipped when /usr/bin/convert or /usr/bin/identify is missing (or is not
ImageMagick), unless PATTERNSHOP_REQUIRE_IMAGEMAGICK=1, where that is an error
(CI sets it). Always the full paths: a bare ``convert`` may be something else.

Measured with ImageMagick 6.9.11-60 Q16 x86_64 (2021-01-25):

IM reading our maps (``convert f.tif txt:``, same numbers as
``-format '%[pixel:p{x,y}]' info:``):

    ours (L, a, b)     8-bit file: IM cielab()        16-bit file: IM cielab()   16-bit hex quanta
    (50, 20, -30)      (50.1961, 19.9981, -29.0019)   (50.0008, 19.9202, -29.8813)  8000 93FF 6200
    (0, -128, 127)     (0, -127.002, 126.998)         (0, -127.5, 126.504)          0000 0000 FEFF
    (100, 127, -128)   (100, 126.998, -127.002)       (100, 126.504, -127.5)        FFFF FEFF 0000
    (25, -5, 5)        (25.098, -4.00195, 4.99805)    (25.0004, -4.9786, 4.9786)    4000 7B00 84FF
    (75, 60, -60)      (74.902, 59.9981, -59.0019)    (74.9996, 59.7646, -59.7646)  BFFF BBFF 4400
    (10, 0, 0)         (10.1961, -0.0019, -0.0019)    (10.0008, -0.0019, -0.0019)   199A 7FFF 7FFF

* identify -verbose: ``Colorspace: CIELab``, ``tiff:photometric: CIELAB``, ``Depth: 8/16-bit``
  (8-bit file) or ``16-bit``, geometry as written; ``identify -format %z`` gives 8 or 16.
* 8 bit: IM shows negative a/b about one unit too high (-5 -> -4.002, -30 -> -29.002);
  its 8-bit hex quanta are int8 + 128, one less for int8 >= 0 (20 -> 0x93, -30 -> 0x62).
* 16 bit: IM interprets a/b on a 255/65535 scale, i.e. value = int16 / 257, where the
  SPEC (Photoshop, libtiff) has int16 / 256; IM's a/b are ours * 256/257.
* IM's raw 16-bit quantum q is int16 + 32768 for negative int16 and int16 + 32767 for
  int16 >= 0 (one below for non-negative values: 5120 -> 0x93FF = 37887, 0 -> 0x7FFF).
  Decoding it with the SPEC formula (q - 32768) / 256 is thus within 1/256 of ours.
* Passing our 16-bit map through ``convert in.tif out.tif`` returns a/b 1/256 low and
  turns a = -128 (int16 -32768) into +127: IM's signed conversion wraps. Not tested.

IM writing Lab TIFFs (``convert srgb.png -colorspace Lab -depth N out.tif``, Photometric 8,
SampleFormat 1), read with read_map, against colour-science (LabMap.from_srgb):

    sRGB              colour-science Lab            16-bit read_map            8-bit read_map
    (200, 100, 50)    (53.626, 36.313, 45.384)      (53.629, 36.449, 45.555)   (53.333, 35, 44)
    (10, 200, 30)     (70.502, -70.513, 64.947)     (70.500, -70.793, 65.191)  (70.196, -73, 64)
    (30, 40, 220)     (31.718, 59.709, -88.925)     (31.714, 59.930, -89.289)  (31.373, 59, -91)
    (128, 128, 128)   (53.585, 0.005, 0.002)        (53.585, 0, -0.008)        (53.333, -2, -2)
    (255, 255, 255)   (100, 0.008, 0.004)           (100, 0, -0.012)           (100, -2, -2)
    (0, 0, 0)         (0, 0, 0)                     (0, 0, 0)                  (0, -2, -2)
    (250, 20, 180)    (56.207, 86.694, -24.811)     (56.213, 87.012, -24.910)  (56.078, 86, -27)
    (90, 200, 210)    (74.910, -28.410, -14.485)    (74.908, -28.531, -14.555) (74.902, -30, -16)

* 16 bit: IM stores a as round(a * 257), so read_map gives a * 257/256 (error |a|/256 <= 0.5);
  after scaling by 256/257 the largest difference was 0.021, L's was 0.005.
* 8 bit: L is truncated (error down to -0.35); a/b come out low: about round(a - 2) for
  a <= 0 (0 -> -2, -70.5 -> -73: -2.49) and about round(a - 1) for positive a.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from synthesis.labmap import LabMap
from synthesis.mapio import encode_lab, read_map, write_tiff

CONVERT = Path("/usr/bin/convert")
IDENTIFY = Path("/usr/bin/identify")


def _imagemagick_problem() -> str | None:
    for tool in (CONVERT, IDENTIFY):
        if not (tool.is_file() and os.access(tool, os.X_OK)):
            return f"{tool} is missing"
        try:
            version = subprocess.run([tool, "-version"], capture_output=True, text=True, timeout=30).stdout
        except (OSError, subprocess.SubprocessError) as exc:
            return f"{tool} does not run ({exc})"
        if "ImageMagick" not in version:
            return f"{tool} is not ImageMagick"
    return None


_PROBLEM = _imagemagick_problem()
if _PROBLEM is not None:
    if os.environ.get("PATTERNSHOP_REQUIRE_IMAGEMAGICK") == "1":
        pytest.fail(f"PATTERNSHOP_REQUIRE_IMAGEMAGICK=1 but {_PROBLEM}", pytrace=False)
    pytest.skip(f"ImageMagick interoperability tests need it: {_PROBLEM}", allow_module_level=True)


# A non-square map (2 rows x 5 columns) of distinct values, positive and negative a/b,
# extremes included; integer a/b so that the 8-bit file stores them exactly.
VALUES = np.array(
    [
        [(50, 20, -30), (0, -128, 127), (100, 127, -128), (25, -5, 5), (75, 60, -60)],
        [(33, 1, -1), (10, 0, 0), (60, -64, 64), (40, 100, -100), (90, -20, 30)],
    ],
    dtype=np.float64,
)

# sRGB patches for maps written by ImageMagick (varied hues, greys, black and white).
PATCHES = np.array(
    [
        [200, 100, 50], [10, 200, 30], [30, 40, 220], [128, 128, 128],
        [255, 255, 255], [0, 0, 0], [250, 20, 180], [90, 200, 210],
    ],
    dtype=np.uint8,
)
PATCH = 4  # pixels per patch side

_TXT_LINE = re.compile(r"^(\d+),(\d+):\s*\(.*?\)\s*#([0-9A-Fa-f]+)\s+cielab\(([^)]*)\)")


# --- helpers --------------------------------------------------------------------------
def im(tool: Path, *args: str | os.PathLike) -> str:
    return subprocess.run([tool, *map(str, args)], capture_output=True, text=True, check=True, timeout=60).stdout


def im_pixels(path: Path, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """IM's view of a Lab TIFF: (H, W, 3) cielab() values and (H, W, 3) raw quanta (hex)."""
    lab = np.full((height, width, 3), np.nan)
    quanta = np.full((height, width, 3), -1, dtype=np.int64)
    for line in im(CONVERT, path, "txt:").splitlines()[1:]:
        match = _TXT_LINE.match(line)
        assert match, f"unexpected IM txt: line {line!r}"
        x, y, hex_digits, values = match.groups()
        digits = len(hex_digits) // 3
        quanta[int(y), int(x)] = [int(hex_digits[k * digits : (k + 1) * digits], 16) for k in range(3)]
        lab[int(y), int(x)] = [float(v) for v in values.split(",")]
    assert not np.isnan(lab).any(), "IM did not report every pixel"
    return lab, quanta


def identify_verbose(path: Path) -> dict[str, str]:
    """The 'Key: value' lines of identify -verbose (first occurrence of each key)."""
    fields: dict[str, str] = {}
    for line in im(IDENTIFY, "-verbose", path).splitlines():
        key, colon, value = line.strip().partition(": ")
        if colon:
            fields.setdefault(key, value.strip())
    return fields


def ours_as_tiff(tmp_path: Path, bits: int) -> Path:
    path = tmp_path / f"ours{bits}.tif"
    write_tiff(LabMap(VALUES), path, bits=bits)
    return path


def im_lab_tiff(tmp_path: Path, bits: int) -> tuple[LabMap, LabMap]:
    """(read_map of IM's Lab TIFF of the patch image, colour-science's map of the same sRGB)."""
    rgb = np.repeat(np.repeat(PATCHES[None], PATCH, axis=0), PATCH, axis=1)
    source, target = tmp_path / "patches.png", tmp_path / f"im{bits}.tif"
    Image.fromarray(rgb, mode="RGB").save(source)
    im(CONVERT, source, "-colorspace", "Lab", "-depth", str(bits), target)
    got = read_map(target)
    assert (got.height, got.width) == (PATCH, PATCH * len(PATCHES))
    return got, LabMap.from_srgb(rgb / 255.0)


# --- IM reads our maps ----------------------------------------------------------------------
@pytest.mark.parametrize("bits", [8, 16])
def test_identify_sees_cielab(tmp_path, bits):
    path = ours_as_tiff(tmp_path, bits)
    fields = identify_verbose(path)
    assert fields["Colorspace"] == "CIELab"
    assert fields["tiff:photometric"] == "CIELAB"
    assert fields["Geometry"] == "5x2+0+0"  # width x height: not transposed
    # IM6 says "8/16-bit" for our 8-bit file (its a/b no longer fit 8 bits once offset).
    assert re.fullmatch(rf"{bits}(/16)?-bit", fields["Depth"])
    assert im(IDENTIFY, "-format", "%z %[colorspace] %w %h", path).split() == [str(bits), "CIELab", "5", "2"]


def test_imagemagick_reads_8bit_map(tmp_path):
    lab, quanta = im_pixels(ours_as_tiff(tmp_path, 8), 2, 5)
    # IM6 reads negative 8-bit a/b about one unit high (-30 -> -29.002); positive ones and
    # L (a multiple of 100/255) are within 0.01.
    np.testing.assert_allclose(lab, VALUES, atol=1.0)
    np.testing.assert_allclose(lab[..., 0], VALUES[..., 0], atol=100 / 255 / 2 + 1e-3)
    # IM's 8-bit quanta: L as stored; a/b as int8 + 128 (one less for int8 >= 0, as at 16 bits)
    raw = encode_lab(LabMap(VALUES), 8)
    np.testing.assert_array_equal(quanta[..., 0], raw[..., 0])
    signed = raw[..., 1:].view(np.int8).astype(np.int64)
    assert np.abs(quanta[..., 1:] - (signed + 128)).max() <= 1


def test_imagemagick_reads_16bit_map(tmp_path):
    lab, quanta = im_pixels(ours_as_tiff(tmp_path, 16), 2, 5)
    np.testing.assert_allclose(lab[..., 0], VALUES[..., 0], atol=0.1)
    # IM6 convention: 16-bit a/b = int16 / 257 (a 255/65535 scale), the SPEC's is int16 / 256,
    # so IM's a/b are ours * 256/257; undo that before comparing.
    np.testing.assert_allclose(lab[..., 1:] * 257 / 256, VALUES[..., 1:], atol=0.1)
    # IM's raw quantum is int16 + 32768 (one less for int16 >= 0); the SPEC formula
    # (q - 32768) / 256 on it gives our values within 1/256.
    raw = encode_lab(LabMap(VALUES), 16)
    np.testing.assert_array_equal(quanta[..., 0], raw[..., 0])
    signed = raw[..., 1:].view(np.int16).astype(np.int64)
    assert np.abs(quanta[..., 1:] - (signed + 32768)).max() <= 1
    np.testing.assert_allclose((quanta[..., 1:] - 32768) / 256, VALUES[..., 1:], atol=0.01)


# --- we read IM's Lab TIFFs -----------------------------------------------------------------
def test_read_imagemagick_16bit_lab_tiff(tmp_path):
    got, want = im_lab_tiff(tmp_path, 16)
    # L: IM and colour-science agree to ~0.005 (measured), 16-bit quantisation is 0.0008.
    np.testing.assert_allclose(got.L, want.L, atol=0.1)
    # a/b: IM writes round(a * 257), so read_map gives a * 257/256 (up to 0.5 off at the
    # extremes); after undoing that, what remains is IM's vs colour-science's conversion
    # (matrix and white-point constants; measured <= 0.021) and quantisation (0.002).
    np.testing.assert_allclose(got.ab * 256 / 257, want.ab, atol=0.15)


def test_read_imagemagick_8bit_lab_tiff(tmp_path):
    got, want = im_lab_tiff(tmp_path, 8)
    # L: IM6 truncates instead of rounding (one 8-bit step is 0.39; measured down to -0.35).
    np.testing.assert_allclose(got.L, want.L, atol=0.6)
    # a/b: IM6's 8-bit Lab writer comes out low, by 1.5-2.5 units for negative a/b
    # (0 -> -2, -70.51 -> -73: -2.49 measured) and 0.5-1.5 for positive ones; 2.5 plus
    # 0.05 for IM's vs colour-science's conversion (<= 0.03 at 16 bits).
    np.testing.assert_allclose(got.ab, want.ab, atol=2.55)
