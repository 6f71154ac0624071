"""Maps from photographs: L from linear luminance, correlation from a preset, a label image or a mask.

Dots add ink linearly in *luminance*: a region whose points cover a fraction c
of the paper reflects Y = 1 - c of the light. A photo's tone is therefore
reproduced by ``density = 1 - Y``, i.e. ``L = 100 Y`` with Y the *linear*
luminance (sRGB decoded, ``Y = 0.2126 R + 0.7152 G + 0.0722 B``), not CIELAB L*:
a mid grey of L* = 50 (sRGB 119) has Y = 0.184 and becomes L = 18.4; taken as
L = 50 it would print far too light (as if it were L* = 76).

The pipeline, per pixel (all arrays float32):

1. Pixel values are read as sRGB (8- or 16-bit grey, RGB, RGBA, palette; EXIF
   orientation applied; embedded ICC profiles are not applied) and decoded to
   linear Y in [0, 1].
2. Photos larger than ``max_side`` pixels on their long side are downsampled by
   area averaging of Y (averaging linear light keeps the tone).
3. ``levels`` (black, white) on the 0-255 scale of the grey value (the
   sRGB-encoded Y, what an editor's colour picker shows for a grey pixel):
   like an editor's Levels, black and darker -> 0, white and lighter -> 1,
   stretched linearly between in encoded values.
4. ``gamma``: ``Y' = Y ** gamma`` (> 1 darkens the mid-tones: more points).
5. ``density = 1 - Y'``, or ``Y'`` with ``invert`` (white dots on black paper);
   transparent pixels are paper: density times alpha. ``L = 100 (1 - density)``.

The map has the (possibly downsampled) photo's pixels, so its domain is the
photo's aspect ratio with the long side 1.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import warnings
from collections.abc import Iterator, Mapping, Sequence

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from synthesis.errors import PatternshopError, PatternshopWarning, require_file
from synthesis.labmap import AB_RANGE, SRGB_TO_XYZ, LabMap, linear_to_srgb, srgb_to_linear

PathLike = str | os.PathLike
AB = tuple[float, float]

MAX_SIDE = 1024  # default long side of the map (px); larger photos are downsampled
MAX_SIDE_LIMIT = 4096  # the largest ``max_side`` accepted (a 4096^2 map is 200 MB as float32 Lab)
LUMINANCE_WEIGHTS = tuple(SRGB_TO_XYZ[1])  # Y of the sRGB primaries: 0.2126 R + 0.7152 G + 0.0722 B
_GREY_MODES = ("1", "L", "LA", "I;16", "I;16B", "I;16L", "I")
_SIXTEEN_BIT_MODES = ("I;16", "I;16B", "I;16L", "I")
_ROWS_PER_STRIP = 256  # rows decoded at once: bounds the float temporaries for very large photos
_ORIENTATION_TAG = 0x0112
_TRANSPOSED_ORIENTATIONS = (5, 6, 7, 8)  # EXIF orientations that swap width and height


# --- options -----------------------------------------------------------------
def parse_correlation(text: str, presets: Mapping[str, AB]) -> AB:
    """A correlation given as a preset name (``blue``) or as ``A,B`` (each in [-128, 127]) -> (a, b).

    Raises:
        PatternshopError: an unknown name, or numbers out of range.
    """
    text = text.strip()
    if text in presets:
        return tuple(float(v) for v in presets[text])  # type: ignore[return-value]
    parts = text.split(",")
    if len(parts) == 2:
        try:
            return check_ab((float(parts[0]), float(parts[1])))
        except ValueError:
            pass
    raise PatternshopError(f"{text!r} is neither a preset ({', '.join(presets)}) nor a colour 'A,B'")


def check_ab(ab: Sequence[float]) -> AB:
    """``ab`` as a float pair, checked to be finite and inside [-128, 127].

    Raises:
        PatternshopError: not two finite numbers in range.
    """
    try:
        a, b = (float(v) for v in ab)
    except (TypeError, ValueError):
        raise PatternshopError(f"a, b must be two numbers in [{AB_RANGE[0]:g}, {AB_RANGE[1]:g}]") from None
    if not all(math.isfinite(v) and AB_RANGE[0] <= v <= AB_RANGE[1] for v in (a, b)):
        raise PatternshopError(f"a, b must be finite and in [{AB_RANGE[0]:g}, {AB_RANGE[1]:g}], got {a:g}, {b:g}")
    return a, b


def parse_label_key(text: str) -> int | tuple[int, int, int]:
    """A label value: an integer grey value or palette index (``3``, ``255``), or a colour ``#rrggbb``.

    Raises:
        PatternshopError: neither form.
    """
    text = text.strip()
    if re.fullmatch(r"#[0-9a-fA-F]{6}", text):
        return int(text[1:3], 16), int(text[3:5], 16), int(text[5:7], 16)
    if re.fullmatch(r"\d+", text) and int(text) <= 65535:
        return int(text)
    raise PatternshopError(f"label {text!r}: give a grey value or palette index 0-65535, or a colour #rrggbb")


# --- reading images ----------------------------------------------------------
@contextlib.contextmanager
def _reading(path: PathLike, what: str) -> Iterator[None]:
    """Turn Pillow's errors inside the block (a truncated or corrupt file) into one error naming the file."""
    try:
        yield
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise PatternshopError(f"{path}: not a readable {what} ({exc})") from exc


def _open(path: PathLike, what: str) -> Image.Image:
    """Open an image's header (no pixels decoded yet); warn that only the first frame or page of several is read."""
    require_file(path, f"{'an' if what[0] in 'aeiou' else 'a'} {what} file")
    with _reading(path, what):
        image = Image.open(path)
        frames = getattr(image, "n_frames", 1)
    if frames > 1:
        warnings.warn(f"{path}: the {what} has {frames} frames or pages; only the first is read", PatternshopWarning,
                      stacklevel=3)
    return image


def _oriented_size(image: Image.Image, path: PathLike, what: str) -> tuple[int, int]:
    """(width, height) after the EXIF orientation is applied, from the header (a PNG's EXIF may need its pixels)."""
    with _reading(path, what):
        orientation = image.getexif().get(_ORIENTATION_TAG, 1)
    return image.size[::-1] if orientation in _TRANSPOSED_ORIENTATIONS else image.size


def _load(image: Image.Image, path: PathLike, what: str) -> Image.Image:
    """Decode the pixels and apply the EXIF orientation."""
    with _reading(path, what):
        image.load()
        return ImageOps.exif_transpose(image)


def _convertible(image: Image.Image, path: PathLike, what: str) -> Image.Image:
    """The image in a mode this module reads: a grey mode, ``P``, ``PA``, ``RGB`` or ``RGBA``."""
    if image.mode in (*_GREY_MODES, "P", "PA", "RGB", "RGBA"):
        return image
    if image.mode == "F":
        raise PatternshopError(f"{path}: floating-point {what}s are not supported (use 8- or 16-bit integers)")
    if image.mode == "LAB":  # Pillow would copy the bands as if they were RGB
        raise PatternshopError(f"{path}: a CIELAB image (a map?) is not a photo; give an sRGB or grey image")
    try:
        return image.convert("RGB")
    except ValueError as exc:
        raise PatternshopError(f"{path}: {what} of colour mode {image.mode} is not supported") from exc


def _luminance_alpha(image: Image.Image) -> tuple[np.ndarray, np.ndarray | None]:
    """(H, W) float32 linear luminance Y in [0, 1] and (H, W) float32 alpha in [0, 1] (None if opaque)."""
    if image.mode in ("P", "PA"):
        image = image.convert("RGBA" if "transparency" in image.info or image.mode == "PA" else "RGB")
    elif image.mode == "1":
        image = image.convert("L")
    sixteen = image.mode in _SIXTEEN_BIT_MODES
    full_scale = 65535 if sixteen else 255
    table = srgb_to_linear(np.arange(full_scale + 1) / full_scale).astype(np.float32)
    height, width = image.height, image.width
    luminance = np.empty((height, width), np.float32)
    alpha = np.empty((height, width), np.float32) if image.mode in ("LA", "RGBA") else None
    for top in range(0, height, _ROWS_PER_STRIP):
        bottom = min(top + _ROWS_PER_STRIP, height)
        strip = np.asarray(image.crop((0, top, width, bottom)))
        if sixteen:
            strip = np.clip(strip, 0, 65535)
        if strip.ndim == 2:
            strip = strip[..., None]
        if strip.shape[2] >= 3:
            rows = sum(w * table[strip[..., c]] for c, w in enumerate(LUMINANCE_WEIGHTS))
        else:
            rows = table[strip[..., 0]]
        luminance[top:bottom] = np.clip(rows, 0.0, 1.0)
        if alpha is not None:
            alpha[top:bottom] = strip[..., -1] / np.float32(255.0)
    return luminance, alpha


def _resize(values: np.ndarray, size: tuple[int, int], resample: Image.Resampling) -> np.ndarray:
    """Resize an (H, W) float32 array to ``size`` = (width, height) with Pillow's float mode."""
    if values.shape[::-1] == size:
        return values
    return np.asarray(Image.fromarray(values.astype(np.float32)).resize(size, resample), np.float32)


def _label_codes(image: Image.Image) -> tuple[np.ndarray, str]:
    """(H, W) int64 label codes and their kind: ``grey`` (values), ``index`` (palette indices) or ``rgb`` (r<<16|g<<8|b)."""
    if image.mode in ("P", "PA"):
        return np.asarray(image.getchannel(0), np.int64), "index"
    if image.mode in _GREY_MODES:
        grey = image.convert("L") if image.mode == "1" else image.getchannel(0) if image.mode == "LA" else image
        return np.asarray(grey, np.int64), "grey"
    rgb = np.asarray(image.convert("RGB"), np.int64)
    return (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2], "rgb"


def _describe(code: int, kind: str) -> str:
    if kind != "rgb":
        return str(code)
    r, g, b = code >> 16, (code >> 8) & 255, code & 255
    return str(r) if r == g == b else f"#{r:02x}{g:02x}{b:02x}"


def _key_mask(codes: np.ndarray, kind: str, key: int | tuple[int, int, int], image: Image.Image) -> np.ndarray:
    """(H, W) bool: pixels whose label is ``key``."""
    if isinstance(key, int):
        if kind == "rgb":
            return codes == (key << 16 | key << 8 | key) if key <= 255 else np.zeros(codes.shape, bool)
        return codes == key
    r, g, b = key
    if kind == "rgb":
        return codes == (r << 16 | g << 8 | b)
    if kind == "grey":
        return codes == r if r == g == b else np.zeros(codes.shape, bool)
    colours = np.asarray(image.getpalette("RGB") or [], np.int64).reshape(-1, 3)
    indices = np.flatnonzero(np.all(colours == (r, g, b), axis=1))
    return np.isin(codes, indices)


# --- the map -----------------------------------------------------------------
def photo_to_map(
    photo: PathLike,
    ab: Sequence[float],
    *,
    gamma: float = 1.0,
    levels: Sequence[float] = (0.0, 255.0),
    invert: bool = False,
    labels: PathLike | None = None,
    label_ab: Mapping[int | tuple[int, int, int], Sequence[float]] | None = None,
    mask: PathLike | None = None,
    mask_ab: Sequence[float] | None = None,
    max_side: int = MAX_SIDE,
) -> LabMap:
    """A map from a photo: L from its linear luminance (module docstring), correlation ``ab`` everywhere, or per region.

    Args:
        photo: any image Pillow reads (8/16-bit grey, RGB, RGBA, palette); EXIF orientation is applied.
        ab: the correlation (a, b) in [-128, 127] of every pixel not set otherwise.
        gamma: tone-curve exponent on Y, > 0 (1: none; > 1 darker mid-tones, more points).
        levels: (black, white) grey values, 0 <= black < white <= 255 (sRGB-encoded, 0-255 scale).
        invert: density = Y' instead of 1 - Y' (white dots on black paper).
        labels: a label image of the photo's size; each pixel whose label is a key of ``label_ab``
            gets that correlation (nearest-neighbour resampling with the photo).
        label_ab: label key (:func:`parse_label_key`: grey value or palette index, or (r, g, b)) -> (a, b).
        mask: a greyscale image of the photo's size; white pixels get ``mask_ab``, black ones ``ab``,
            grey blends linearly in (a, b).
        mask_ab: the correlation where ``mask`` is white.
        max_side: the map's long side is at most this many pixels (1 to :data:`MAX_SIDE_LIMIT`); larger
            photos are downsampled (area average of Y) with a :class:`PatternshopWarning`.

    Returns:
        A :class:`LabMap` of the photo's (downsampled) size; its domain is the photo's aspect, long side 1.

    Raises:
        PatternshopError: a bad option, a missing or unreadable image, a label or mask image of another
            size than the photo, or a label key that does not occur in the label image.
    """
    ab = check_ab(ab)
    if not (math.isfinite(gamma) and gamma > 0):
        raise PatternshopError(f"gamma must be a finite number > 0, got {gamma:g}")
    black, white = (float(v) for v in levels)
    if not (0.0 <= black < white <= 255.0):
        raise PatternshopError(f"levels need 0 <= black < white <= 255, got {black:g} {white:g}")
    if not (isinstance(max_side, int) and 1 <= max_side <= MAX_SIDE_LIMIT):
        raise PatternshopError(f"max_side must be an integer in [1, {MAX_SIDE_LIMIT}], got {max_side!r}")
    if labels is not None and mask is not None:
        raise PatternshopError("give a label image or a mask, not both")
    if (labels is None) != (not label_ab):
        raise PatternshopError("a label image needs label colours, and label colours need a label image")
    if (mask is None) != (mask_ab is None):
        raise PatternshopError("a mask needs a mask colour, and a mask colour needs a mask")
    label_ab = {key: check_ab(value) for key, value in (label_ab or {}).items()}
    mask_ab = check_ab(mask_ab) if mask_ab is not None else None

    # headers first: every size is checked before any pixel is decoded
    source = _open(photo, "image")
    size = _oriented_size(source, photo, "image")
    region_path = labels if labels is not None else mask
    region_what = "label image" if labels is not None else "mask"
    region = _open(region_path, region_what) if region_path is not None else None
    if region is not None and _oriented_size(region, region_path, region_what) != size:
        rw, rh = _oriented_size(region, region_path, region_what)
        raise PatternshopError(f"{region_path}: {rw}x{rh} px, the photo {size[0]}x{size[1]} px (make it at the photo's size)")
    scale = min(1.0, max_side / max(size))
    out_size = (max(1, round(size[0] * scale)), max(1, round(size[1] * scale)))

    chroma = np.empty((out_size[1], out_size[0], 2), np.float32)
    chroma[...] = ab
    if labels is not None:
        image = _convertible(_load(region, labels, "label image"), labels, "label image")
        codes, kind = _label_codes(image)
        if out_size != size:
            codes = np.asarray(Image.fromarray(codes.astype(np.int32)).resize(out_size, Image.Resampling.NEAREST),
                               np.int64)
        for key, value in label_ab.items():
            selected = _key_mask(codes, kind, key, image)
            if not selected.any():
                found = ", ".join(_describe(int(c), kind) for c in np.unique(codes)[:20])
                name = key if isinstance(key, int) else "#{:02x}{:02x}{:02x}".format(*key)
                raise PatternshopError(f"{labels}: no pixel has label {name} (labels found: {found})")
            chroma[selected] = value
    elif mask is not None:
        image = _convertible(_load(region, mask, "mask"), mask, "mask")
        if image.mode in _SIXTEEN_BIT_MODES:
            weight = np.clip(np.asarray(image, np.float32) / 65535.0, 0.0, 1.0)
        else:
            weight = np.asarray(image.convert("L"), np.float32) / 255.0
        weight = np.clip(_resize(weight, out_size, Image.Resampling.BOX), 0.0, 1.0)[..., None]
        chroma = (1.0 - weight) * chroma + weight * np.asarray(mask_ab, np.float32)

    luminance, alpha = _luminance_alpha(_convertible(_load(source, photo, "image"), photo, "image"))
    if out_size != size:
        warnings.warn(f"{photo}: {size[0]}x{size[1]} px downsampled to {out_size[0]}x{out_size[1]} "
                      f"(max side {max_side} px)", PatternshopWarning, stacklevel=2)
        if alpha is not None:  # average the premultiplied luminance, so transparent pixels do not count
            covered = _resize(alpha, out_size, Image.Resampling.BOX)
            luminance = _resize(luminance * alpha, out_size, Image.Resampling.BOX) / np.maximum(covered, 1e-12)
            alpha = covered
        else:
            luminance = _resize(luminance, out_size, Image.Resampling.BOX)
    density = luminance_to_density(luminance, gamma=gamma, levels=(black, white), invert=invert)
    if alpha is not None:
        density = density * np.clip(alpha, 0.0, 1.0)
    return LabMap(np.concatenate([(100.0 * (1.0 - density))[..., None], chroma], axis=-1))


def luminance_to_density(luminance: np.ndarray, gamma: float = 1.0, levels: Sequence[float] = (0.0, 255.0),
         invert: bool = False) -> np.ndarray:
    """Density (H, W) float32 in [0, 1] from linear luminance Y (H, W) in [0, 1]: levels, then ``Y ** gamma``, then 1 - Y'.

    ``levels`` (black, white) are grey values on the 0-255 sRGB-encoded scale; with ``invert`` the density is Y'.
    """
    black, white = (float(v) / 255.0 for v in levels)
    y = np.clip(np.asarray(luminance, np.float64), 0.0, 1.0)
    if (black, white) != (0.0, 1.0):
        encoded = np.clip((linear_to_srgb(y) - black) / (white - black), 0.0, 1.0)
        y = srgb_to_linear(encoded)
    if gamma != 1.0:
        y = y**gamma
    return (y if invert else 1.0 - y).astype(np.float32)
