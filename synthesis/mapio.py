"""Reading and writing maps: CIELAB/ICCLAB TIFF, sRGB images, channel PNGs, previews.

Stored values (SPEC §3):

* CIELAB TIFF (Photometric 8), 8-bit: L = round(L * 255/100) as uint8, a and b as
  int8. 16-bit: L = round(L * 65535/100) as uint16, a and b as int16 =
  round(v * 256). This is the encoding Photoshop and libtiff use.
* ICCLAB TIFF (Photometric 9) is read: a and b are unsigned with an offset of
  128 (8-bit) or scaled over the full range 0..65535 -> [-128, 127] (16-bit).
* Channel PNGs: three 16-bit greyscale PNGs ``NAME.L.png``, ``NAME.a.png``,
  ``NAME.b.png`` holding the fraction of full scale: L = 100 f, a = 255 f - 128
  (so the a/b images are the latent z itself). 8-bit channel PNGs are read too.
* sRGB images (PNG, JPEG, RGB/grey TIFF) are converted to CIELAB (D65) with a
  warning, since 8-bit sRGB quantises chroma and JPEG blurs it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import tifffile

from synthesis.atomic import atomic_path, atomic_paths
from synthesis.errors import MapFormatError, PatternshopError, PatternshopWarning, require_file
from synthesis.labmap import LabMap
from synthesis.version import version_string

if TYPE_CHECKING:  # Pillow is imported where an image is read or written: a TIFF map's synthesis never needs it
    from PIL import Image

TIFF_SUFFIXES = (".tif", ".tiff")
SRGB_SUFFIXES = (".png", ".jpg", ".jpeg")
CHANNELS = ("L", "a", "b")
_PHOTOMETRIC_CIELAB = 8
_PHOTOMETRIC_ICCLAB = 9
_PHOTOMETRIC_GREY = 1
_PHOTOMETRIC_RGB = 2
_TIFF_DESCRIPTION = "Patternshop map: L = 100 (1 - density); a, b = 255 z - 128 (correlation latent z)"

PathLike = str | os.PathLike


# --- channel-PNG names -------------------------------------------------------
def channel_paths(path: PathLike) -> tuple[Path, Path, Path]:
    """The three channel-PNG paths for ``path``.

    ``face.png``, ``face.L.png``, ``face.a.png`` and ``face`` all give
    ``(face.L.png, face.a.png, face.b.png)``.
    """
    path = Path(path)
    name = path.name
    for channel in CHANNELS:
        if name.endswith(f".{channel}.png"):
            name = name[: -len(".L.png")]
            break
    else:
        if name.lower().endswith(".png"):
            name = name[:-4]
    return tuple(path.with_name(f"{name}.{c}.png") for c in CHANNELS)  # type: ignore[return-value]


def is_channel_path(path: PathLike) -> bool:
    """True when ``path`` names one image of a channel-PNG triplet (``*.L.png`` ...)."""
    return any(Path(path).name.endswith(f".{c}.png") for c in CHANNELS)


# --- reading -----------------------------------------------------------------
@contextlib.contextmanager
def _quiet_tifffile() -> Iterator[None]:
    """Keep tifffile's log lines about broken files off stderr: the reader's exception says what is wrong."""
    logger = logging.getLogger("tifffile")
    disabled, logger.disabled = logger.disabled, True
    try:
        yield
    finally:
        logger.disabled = disabled


def _reason(exc: BaseException) -> str:
    """A library exception as a reason: its message, or "truncated or corrupt" when it has no words (``IndexError: 0``)."""
    text = " ".join(str(exc).split())
    return text if any(c.isalpha() for c in text) else "truncated or corrupt"


def map_size(path: PathLike) -> tuple[int, int]:
    """(width, height) in pixels of a map file, read from its header (no pixels decoded).

    Raises:
        MapFormatError: the file is missing, unreadable or of an unsupported kind.
    """
    path = Path(path)
    if is_channel_path(path):
        path = channel_paths(path)[0]
    require_file(path, "a map file", MapFormatError)
    suffix = path.suffix.lower()
    if suffix in TIFF_SUFFIXES:
        try:
            with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
                page = tif.pages.first
                return int(page.imagewidth), int(page.imagelength)
        except (tifffile.TiffFileError, ValueError, OSError, KeyError, IndexError, RuntimeError) as exc:
            raise MapFormatError(f"{path}: not a readable TIFF ({_reason(exc)})") from exc
    if suffix in SRGB_SUFFIXES:
        from PIL import Image, UnidentifiedImageError

        try:
            with Image.open(path) as image:
                return image.size
        except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as exc:
            raise MapFormatError(f"{path}: not a readable image ({_reason(exc)})") from exc
    raise MapFormatError(
        f"{path}: unsupported map format '{path.suffix}' "
        "(use a CIELAB .tif, channel PNGs NAME.L.png/.a.png/.b.png, or an sRGB .png/.jpg)"
    )


def read_map(path: PathLike) -> LabMap:
    """Read a map from a CIELAB/ICCLAB/RGB TIFF, a channel-PNG triplet or an sRGB image.

    Raises:
        MapFormatError: the file is missing, unreadable or of an unsupported kind.
    """
    path = Path(path)
    if is_channel_path(path):
        return read_channels(path)
    require_file(path, "a map file", MapFormatError)
    suffix = path.suffix.lower()
    if suffix in TIFF_SUFFIXES:
        return _read_tiff(path)
    if suffix in SRGB_SUFFIXES:
        return _read_srgb_image(path)
    raise MapFormatError(
        f"{path}: unsupported map format '{path.suffix}' "
        "(use a CIELAB .tif, channel PNGs NAME.L.png/.a.png/.b.png, or an sRGB .png/.jpg)"
    )


def _read_tiff(path: Path) -> LabMap:
    try:
        with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
            page = tif.pages.first
            photometric = int(page.photometric)
            bits = page.bitspersample
            sampleformat = int(page.sampleformat)
            pixels = page.asarray()
            axes = page.axes
            pages = sum(not getattr(p, "is_reduced", False) for p in tif.pages)  # thumbnails are no pages of their own
    except (tifffile.TiffFileError, ValueError, OSError, KeyError, IndexError, RuntimeError) as exc:
        # RuntimeError: imagecodecs' decoder errors (e.g. a truncated deflate stream)
        raise MapFormatError(f"{path}: not a readable TIFF ({_reason(exc)})") from exc
    if pages > 1:
        _warn_ignored(path, f"the TIFF has {pages} pages; only the first is read")
    pixels = _to_height_width_samples(pixels, axes, path)
    if photometric in (_PHOTOMETRIC_CIELAB, _PHOTOMETRIC_ICCLAB):
        if sampleformat == 3 or bits not in (8, 16):
            raise MapFormatError(f"{path}: Lab TIFF with {bits}-bit samples is not supported (use 8 or 16 bit integers)")
        if pixels.shape[2] < 3:
            raise MapFormatError(f"{path}: Lab TIFF with {pixels.shape[2]} samples per pixel (need 3)")
        if pixels.shape[2] > 3:
            _warn_ignored(path, f"the Lab TIFF has {pixels.shape[2]} samples per pixel: only L, a, b are read, "
                          f"the extra {pixels.shape[2] - 3} (alpha) ignored")
        return _decode_lab(pixels[..., :3], bits, icc=photometric == _PHOTOMETRIC_ICCLAB)
    if photometric in (_PHOTOMETRIC_GREY, _PHOTOMETRIC_RGB):
        _warn_srgb(path)
        return LabMap.from_srgb(_normalised_rgb(pixels, path))
    raise MapFormatError(
        f"{path}: TIFF photometric interpretation {photometric} is not supported (use CIELAB, ICCLAB, RGB or grey)"
    )


def _to_height_width_samples(pixels: np.ndarray, axes: str, path: Path) -> np.ndarray:
    """Bring a TIFF page array into (H, W, S) order."""
    axes = axes.replace("Q", "")
    if "Y" not in axes or "X" not in axes:
        raise MapFormatError(f"{path}: TIFF page has unexpected axes '{axes}'")
    if "S" not in axes:
        pixels, axes = pixels[..., None], axes + "S"
    pixels = pixels.reshape([n for n, ax in zip(pixels.shape, axes) if ax in "YXS"])
    axes = "".join(ax for ax in axes if ax in "YXS")
    return np.transpose(pixels, [axes.index(ax) for ax in "YXS"])


def _decode_lab(raw: np.ndarray, bits: int, icc: bool) -> LabMap:
    """Decode (H, W, 3) raw Lab samples of 8 or 16 bits (any signedness) to a map."""
    unsigned = raw.view(np.uint8 if bits == 8 else np.uint16)
    full_scale = 255.0 if bits == 8 else 65535.0
    lab = np.empty(raw.shape, np.float32)
    lab[..., 0] = unsigned[..., 0] * (100.0 / full_scale)
    if icc:
        lab[..., 1:] = unsigned[..., 1:] * (255.0 / full_scale) - 128.0
    else:
        signed = unsigned.view(np.int8 if bits == 8 else np.int16)
        lab[..., 1:] = signed[..., 1:] * (1.0 if bits == 8 else 1.0 / 256.0)
    return LabMap(lab)


def _normalised_rgb(pixels: np.ndarray, path: Path) -> np.ndarray:
    """(H, W, S) integer RGB(A) or grey(A) samples -> (H, W, 3) float in [0, 1]."""
    if not np.issubdtype(pixels.dtype, np.integer):
        raise MapFormatError(f"{path}: floating-point RGB images are not supported")
    rgb = pixels.astype(np.float64) / np.iinfo(pixels.dtype).max
    channels = rgb.shape[2]
    if channels in (2, 4):
        _warn_ignored(path, "the alpha channel is ignored (a map has no transparency)")
    if channels in (1, 2):  # grey, grey + alpha
        return np.repeat(rgb[..., :1], 3, axis=2)
    return rgb[..., :3]


def _warn_ignored(path: Path, what: str) -> None:
    """Warn that part of a map file (pages, channels) is not read."""
    warnings.warn(f"{path}: {what}", PatternshopWarning, stacklevel=4)


def _warn_srgb(path: Path) -> None:
    message = f"{path}: sRGB image converted to CIELAB (D65); 8-bit sRGB quantises correlation colours"
    if path.suffix.lower() in (".jpg", ".jpeg"):
        message += ", and JPEG chroma subsampling blurs correlation edges"
    warnings.warn(message + " (prefer a CIELAB TIFF or channel PNGs)", PatternshopWarning, stacklevel=3)


def _open_image(path: Path) -> Image.Image:
    from PIL import Image, UnidentifiedImageError

    try:
        image = Image.open(path)
        image.load()
        frames = getattr(image, "n_frames", 1)
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as exc:
        raise MapFormatError(f"{path}: not a readable image ({_reason(exc)})") from exc
    if frames > 1:
        _warn_ignored(path, f"the image has {frames} frames; only the first is read")
    return image


def _read_srgb_image(path: Path) -> LabMap:
    from PIL import ImageOps

    image = ImageOps.exif_transpose(_open_image(path))
    _warn_srgb(path)
    if image.has_transparency_data:
        _warn_ignored(path, "the alpha channel is ignored (a map has no transparency)")
    if image.mode in ("I;16", "I;16B", "I;16L", "I"):
        grey = np.asarray(image, dtype=np.float64) / 65535.0
        rgb = np.repeat(np.clip(grey, 0.0, 1.0)[..., None], 3, axis=2)
    else:
        rgb = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
    return LabMap.from_srgb(rgb)


def _read_channel_image(path: Path) -> np.ndarray:
    """One channel PNG -> (H, W) float64 fraction of full scale in [0, 1]."""
    require_file(path, "a channel PNG", MapFormatError,
                 "no such file (channel PNGs come in threes: NAME.L.png, NAME.a.png, NAME.b.png)")
    image = _open_image(path)
    if image.mode in ("I;16", "I;16B", "I;16L", "I"):
        return np.clip(np.asarray(image, dtype=np.float64) / 65535.0, 0.0, 1.0)
    if image.mode in ("L", "LA"):
        return np.asarray(image.getchannel(0), dtype=np.float64) / 255.0
    if image.mode in ("RGB", "RGBA"):
        rgb = np.asarray(image, dtype=np.float64)[..., :3]
        if np.any(rgb != rgb[..., :1]):
            raise MapFormatError(f"{path}: a channel PNG must be greyscale, this one has colour")
        return rgb[..., 0] / 255.0
    raise MapFormatError(f"{path}: channel PNG of mode {image.mode} is not supported (use 8- or 16-bit greyscale)")


def read_channels(path: PathLike) -> LabMap:
    """Read the channel-PNG triplet named by ``path`` (any of the three, or their stem)."""
    fractions = [_read_channel_image(p) for p in channel_paths(path)]
    shapes = {f.shape for f in fractions}
    if len(shapes) != 1:
        raise MapFormatError(f"{path}: channel PNGs differ in size: {sorted(shapes)}")
    L, a, b = fractions
    return LabMap(np.stack([100.0 * L, 255.0 * a - 128.0, 255.0 * b - 128.0], axis=-1))


# --- writing -----------------------------------------------------------------
def encode_lab(lab_map: LabMap, bits: int) -> np.ndarray:
    """Raw CIELAB TIFF samples (H, W, 3): uint8 for 8 bits, uint16 for 16 bits.

    a and b are two's-complement signed values stored in the unsigned array, as
    TIFF CIELAB requires (L unsigned, a and b signed, one sample format).
    """
    L, ab = lab_map.L.astype(np.float64), lab_map.ab.astype(np.float64)
    if bits == 8:
        out = np.empty(lab_map.lab.shape, np.uint8)
        out[..., 0] = np.rint(L * 255.0 / 100.0)
        out[..., 1:] = np.clip(np.rint(ab), -128, 127).astype(np.int8).view(np.uint8)
    elif bits == 16:
        out = np.empty(lab_map.lab.shape, np.uint16)
        out[..., 0] = np.rint(L * 65535.0 / 100.0)
        out[..., 1:] = np.clip(np.rint(ab * 256.0), -32768, 32767).astype(np.int16).view(np.uint16)
    else:
        raise MapFormatError(f"bit depth must be 8 or 16, got {bits}")
    return out


def write_tiff(lab_map: LabMap, path: PathLike, bits: int = 16) -> None:
    """Write a CIELAB TIFF (Photometric 8; horizontal differencing, then deflate at level 1) atomically.

    Differencing first makes the smooth channels of a map compress better and faster: a 256-px 16-bit map of
    ``convert`` took 4.5 ms and 277 kB, against 5.8 ms and 332 kB with plain deflate at zlib's default level 6.
    """
    raw = encode_lab(lab_map, bits)
    with atomic_path(path) as tmp:
        tifffile.imwrite(
            tmp,
            raw,
            photometric=_PHOTOMETRIC_CIELAB,
            planarconfig="contig",
            compression="zlib",
            compressionargs={"level": 1},
            predictor=True,
            description=_TIFF_DESCRIPTION,
            software=version_string(),
            metadata=None,
        )


def write_channels(lab_map: LabMap, path: PathLike) -> tuple[Path, Path, Path]:
    """Write the map as three 16-bit greyscale PNGs (see module docstring); returns their paths."""
    from PIL import Image

    targets = channel_paths(path)
    fractions = (lab_map.L / 100.0, (lab_map.ab[..., 0] + 128.0) / 255.0, (lab_map.ab[..., 1] + 128.0) / 255.0)
    with atomic_paths(targets) as temporary:
        for fraction, tmp in zip(fractions, temporary):
            values = np.rint(np.clip(fraction, 0.0, 1.0) * 65535.0).astype(np.uint16)
            Image.fromarray(values).save(tmp, format="PNG")
    return targets


def write_map(lab_map: LabMap, path: PathLike, bits: int = 16) -> None:
    """Write a map losslessly: ``.tif``/``.tiff`` as CIELAB, ``NAME.L.png`` etc. as channel PNGs."""
    path = Path(path)
    if path.suffix.lower() in TIFF_SUFFIXES:
        write_tiff(lab_map, path, bits)
    elif is_channel_path(path):
        write_channels(lab_map, path)
    else:
        raise MapFormatError(
            f"{path}: maps are written as CIELAB .tif or channel PNGs NAME.L.png "
            "(an sRGB .png is a lossy preview: use write_preview / 'patternshop preview')"
        )


def write_preview(lab_map: LabMap, path: PathLike, scale: int = 1) -> None:
    """Write an 8-bit sRGB PNG of the map (out-of-gamut colours clipped), ``scale`` x enlarged."""
    if scale < 1:
        raise PatternshopError(f"preview scale must be >= 1, got {scale}")
    from PIL import Image

    image = Image.fromarray(lab_map.to_srgb8())
    if scale > 1:
        image = image.resize((image.width * scale, image.height * scale), Image.Resampling.NEAREST)
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG")
