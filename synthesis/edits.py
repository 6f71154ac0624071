"""Map edits as pure functions on :class:`~synthesis.labmap.LabMap`: correlation of a region, density gradients,
canvas expansion, resizing. Each returns a new map.

Coordinates are map units: the domain ``[0, w] x [0, h]`` (``max(w, h) = 1``),
origin at the top-left, y down; pixel (i, j) of an (H, W) map has its centre at
``((j + 0.5), (i + 0.5)) / max(H, W)``. A *region* is an (H, W) float32 weight
in [0, 1]: 1 where an edit applies, 0 where the map is kept, values in between
blend the two (soft mask edges). Density is ``d = 1 - L/100`` in [0, 1].
"""

from __future__ import annotations

import os

import numpy as np
from PIL import Image

from synthesis.errors import PatternshopError, require_file
from synthesis.labmap import AB_RANGE, L_RANGE, LabMap, resample_map
from synthesis.patchfill import content_aware_fill
from synthesis.photo import _reading, check_ab

GRADIENT_MODES = ("set", "multiply")
FILL_MODES = ("edge", "content-aware")  # expand's fills besides a colour

PathLike = str | os.PathLike


def pixel_centres(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """x and y, each (H, W) float64, of the pixel centres of an (H, W) map, in map units."""
    height, width = shape
    side = max(height, width)
    y, x = np.meshgrid((np.arange(height) + 0.5) / side, (np.arange(width) + 0.5) / side, indexing="ij")
    return x, y


def rect_region(shape: tuple[int, int], rect: tuple[float, float, float, float]) -> np.ndarray:
    """(H, W) float32 region: 1 where the pixel centre lies in the rectangle (x0, y0, x1, y1) (map units), else 0."""
    x0, y0, x1, y1 = rect
    if not (x0 < x1 and y0 < y1):
        raise PatternshopError(f"rectangle needs x0 < x1 and y0 < y1, got ({x0:g}, {y0:g}, {x1:g}, {y1:g})")
    x, y = pixel_centres(shape)
    return ((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)).astype(np.float32)


def read_region(path: PathLike, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) float32 region from a greyscale mask image of the map's size: white 1 (edit), black 0 (keep), grey blends.

    Colour masks count by their luminance; 16-bit greyscale PNGs are read at full precision.

    Raises:
        PatternshopError: missing or unreadable image, or not (H, W) pixels.
    """
    require_file(path, "a mask image file")
    with _reading(path, "mask image"), Image.open(path) as image:
        image.load()
        if image.mode in ("I;16", "I;16B", "I;16L", "I"):
            region = np.asarray(image, np.float64) / 65535.0
        else:
            region = np.asarray(image.convert("L"), np.float64) / 255.0
    if region.shape != tuple(shape):
        raise PatternshopError(f"{path}: mask is {region.shape[1]}x{region.shape[0]} px, the map {shape[1]}x{shape[0]} px "
                               "(make the mask at the map's size)")
    return np.clip(region, 0.0, 1.0).astype(np.float32)


def _weights(lab_map: LabMap, region: np.ndarray | None) -> np.ndarray:
    """(H, W) float32 blend weights: the region, or 1 everywhere."""
    if region is None:
        return np.ones(lab_map.lab.shape[:2], np.float32)
    region = np.asarray(region, np.float32)
    if region.shape != lab_map.lab.shape[:2]:
        raise PatternshopError(f"region of shape {region.shape} does not match the map's {lab_map.lab.shape[:2]}")
    return np.clip(region, 0.0, 1.0)


def set_correlation(lab_map: LabMap, ab: tuple[float, float], region: np.ndarray | None = None) -> LabMap:
    """The map with a, b set to ``ab`` (each in [-128, 127]) inside ``region`` (default: everywhere); L unchanged."""
    target = np.asarray(check_ab(ab), np.float32)
    weight = _weights(lab_map, region)[..., None]
    lab = lab_map.lab.copy()
    lab[..., 1:] = (1.0 - weight) * lab[..., 1:] + weight * target
    return LabMap(lab)


def linear_ramp(shape: tuple[int, int], start: tuple[float, float], end: tuple[float, float],
                values: tuple[float, float]) -> np.ndarray:
    """(H, W) float32: ``values[0]`` at ``start``, ``values[1]`` at ``end`` (x, y in map units), linear along the
    line between them and constant beyond its ends (lines across the direction have one value)."""
    (x0, y0), (x1, y1) = start, end
    dx, dy = x1 - x0, y1 - y0
    length2 = dx * dx + dy * dy
    if length2 == 0:
        raise PatternshopError(f"gradient start and end are the same point ({x0:g}, {y0:g})")
    x, y = pixel_centres(shape)
    t = np.clip(((x - x0) * dx + (y - y0) * dy) / length2, 0.0, 1.0)
    return (values[0] + t * (values[1] - values[0])).astype(np.float32)


def density_gradient(lab_map: LabMap, start: tuple[float, float], end: tuple[float, float], values: tuple[float, float],
                     mode: str = "set", region: np.ndarray | None = None) -> LabMap:
    """The map with a linear density gradient from ``start`` to ``end`` (see :func:`linear_ramp`) inside ``region``;
    a, b unchanged.

    Args:
        mode: ``"set"``: density becomes the ramp, ``values`` are densities in [0, 1];
            ``"multiply"``: density is multiplied by the ramp (clipped to [0, 1]),
            ``values`` are factors >= 0, so the existing tone keeps its shape.
    """
    if mode not in GRADIENT_MODES:
        raise PatternshopError(f"gradient mode must be one of {GRADIENT_MODES}, got {mode!r}")
    low = min(values)
    if low < 0 or (mode == "set" and max(values) > 1):
        bounds = "densities in [0, 1]" if mode == "set" else "factors >= 0"
        raise PatternshopError(f"gradient values must be {bounds} in mode {mode}, got {values[0]:g}, {values[1]:g}")
    ramp = linear_ramp(lab_map.lab.shape[:2], start, end, values)
    density = lab_map.density()
    changed = ramp if mode == "set" else np.clip(density * ramp, 0.0, 1.0)
    weight = _weights(lab_map, region)
    lab = lab_map.lab.copy()
    lab[..., 0] = 100.0 * (1.0 - ((1.0 - weight) * density + weight * changed))
    return LabMap(lab)


def expand(lab_map: LabMap, margins: tuple[int, int, int, int],
           fill: tuple[float, float, float] | str | None = None, *, seed: int = 0) -> LabMap:
    """The map on a larger canvas: ``margins`` = (left, top, right, bottom) pixels added.

    The new pixels take ``fill`` = (L, a, b); or repeat the nearest edge pixel when ``fill`` is None or ``"edge"``;
    or, with ``"content-aware"``, more of the map's texture (:func:`synthesis.patchfill.content_aware_fill`,
    deterministic for a ``seed``). The domain grows with the canvas (its long side is 1 again).
    """
    left, top, right, bottom = (int(m) for m in margins)
    if min(left, top, right, bottom) < 0:
        raise PatternshopError(f"margins must be >= 0 pixels, got {left}, {top}, {right}, {bottom}")
    padding = ((top, bottom), (left, right), (0, 0))
    if isinstance(fill, str) and fill not in FILL_MODES:
        raise PatternshopError(f"fill must be (L, a, b) or one of {', '.join(FILL_MODES)}, got {fill!r}")
    if fill == "content-aware":
        edge = np.pad(lab_map.lab, padding, mode="edge")
        hole = np.ones(edge.shape[:2], bool)
        hole[top : top + lab_map.height, left : left + lab_map.width] = False
        return LabMap(content_aware_fill(edge, hole, seed=seed))
    if fill is None or fill == "edge":
        return LabMap(np.pad(lab_map.lab, padding, mode="edge"))
    if not (L_RANGE[0] <= fill[0] <= L_RANGE[1] and all(AB_RANGE[0] <= v <= AB_RANGE[1] for v in fill[1:])):
        raise PatternshopError(f"fill needs L in [0, 100] and a, b in [-128, 127], got {', '.join(f'{float(v):g}' for v in fill)}")
    expanded = np.empty((lab_map.height + top + bottom, lab_map.width + left + right, 3), np.float32)
    expanded[...] = np.asarray(fill, np.float32)
    expanded[top : top + lab_map.height, left : left + lab_map.width] = lab_map.lab
    return LabMap(expanded)


def resize(lab_map: LabMap, width: int, height: int | None = None) -> LabMap:
    """The map resampled to ``width`` pixels wide and ``height`` high (default: aspect kept, rounded, at least 1).

    Bilinear per channel (L, a, b), antialiased when shrinking.
    """
    if width < 1 or (height is not None and height < 1):
        raise PatternshopError(f"width and height must be at least 1 pixel, got {width} and {height}")
    height = height if height is not None else max(1, round(width * lab_map.height / lab_map.width))
    return resample_map(lab_map, (height, width))
