"""The studio's map edits: pure functions on an (H, W, 3) float32 CIELAB array, one per tool.

An edit arrives from the page as a JSON object with a ``type``; :func:`apply_edit` validates it (a bad one
raises :class:`~synthesis.errors.PatternshopError` with a one-line message) and returns the new array.
Positions are in **map pixels**, continuous: pixel (row i, column j) has its centre at (j + 0.5, i + 0.5).

Brushes (``density``, ``correlation``, ``eraser``) share one stroke weight, repeated exactly by
``static/studio.js`` so the page repaints a stroke before the server has it:

* a stamp at centre c with radius R = size / 2 weighs a pixel at distance r from c by 1 inside h R
  (h = hardness), 0 beyond R, and a smoothstep ``t^2 (3 - 2t)``, t = (R - r) / (R - h R), in between;
* a stroke's weight is ``w = strength x max over its stamps`` (painting over the same place within one
  stroke does not build up, as with a brush's opacity in an image editor);
* ``density`` darken: ``L' = L (1 - w)``; lighten: ``L' = L + w (100 - L)``; ``correlation``:
  ``ab' = ab + w (target - ab)``; ``eraser``: ``lab' = lab + w (opened - lab)`` where the opened map lies.

Other edits: ``fill`` (a selection gets a colour and/or a density: a rectangle ``rect``, a lasso
``polygon``, or the pixels of similar colour around a ``seed``, the magic wand), ``gradient`` (a linear density ramp,
:func:`synthesis.edits.density_gradient`), ``expand`` (a larger canvas, :func:`synthesis.edits.expand`; its new area repeats the edge, takes a colour, or
is filled content-aware).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from synthesis.edits import density_gradient, expand, rect_region, set_correlation
from synthesis.errors import PatternshopError
from synthesis.labmap import LabMap

MAX_STAMPS = 20_000  # stamps in one stroke
MAX_BRUSH_SIZE = 4096.0  # brush diameter, pixels
MAX_SIDE = 8192  # a map side after canvas expansion, pixels
MAX_STROKE_WORK = 2e9  # stamps x stamp pixels in one stroke (a few seconds of work)
EDIT_TYPES = ("density", "correlation", "eraser", "fill", "gradient", "expand")
LABELS = {"density": "density brush", "correlation": "correlation brush", "eraser": "eraser", "fill": "fill",
          "gradient": "density gradient", "expand": "canvas expansion"}


@dataclass(frozen=True)
class EditResult:
    """The map after an edit and where the opened map now lies in it (its top-left pixel)."""

    lab: np.ndarray
    offset: tuple[int, int]
    label: str


# --- validation of JSON values -----------------------------------------------------------------------------
def _number(edit: dict, key: str, low: float | None = None, high: float | None = None, default: Any = None) -> float:
    value = edit.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise PatternshopError(f"{key} must be a finite number, got {value!r}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise PatternshopError(f"{key} must be in [{low:g}, {high:g}], got {value:g}")
    return float(value)


def _pair(value: Any, name: str, low: float | None = None, high: float | None = None) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise PatternshopError(f"{name} must be a pair of numbers, got {value!r}")
    return _number({name: value[0]}, name, low, high), _number({name: value[1]}, name, low, high)


def _ab(value: Any, name: str = "ab") -> tuple[float, float]:
    return _pair(value, name, -128.0, 127.0)


def _centres(edit: dict) -> np.ndarray:
    centres = edit.get("centres")
    if not isinstance(centres, list) or not centres:
        raise PatternshopError("a brush stroke needs centres: a list of [x, y] positions in map pixels")
    if len(centres) > MAX_STAMPS:
        raise PatternshopError(f"a stroke has at most {MAX_STAMPS} stamps, got {len(centres)}")
    try:
        array = np.asarray(centres, np.float64)
    except (TypeError, ValueError):
        raise PatternshopError("centres must be [x, y] pairs of numbers") from None
    if array.ndim != 2 or array.shape[1] != 2 or not np.all(np.isfinite(array)):
        raise PatternshopError("centres must be [x, y] pairs of finite numbers")
    return array


# --- the brush ---------------------------------------------------------------------------------------------
def stroke_weight(shape: tuple[int, int], centres: np.ndarray, size: float, hardness: float,
                  strength: float) -> tuple[np.ndarray, tuple[int, int, int, int]] | None:
    """The stroke's weight on its bounding box: ((y1 - y0, x1 - x0) float64, (y0, y1, x0, x1)); None off the map."""
    height, width = shape
    radius = size / 2.0
    inner = hardness * radius
    x0 = max(0, int(math.floor(float(centres[:, 0].min()) - radius)))
    x1 = min(width, int(math.ceil(float(centres[:, 0].max()) + radius)) + 1)
    y0 = max(0, int(math.floor(float(centres[:, 1].min()) - radius)))
    y1 = min(height, int(math.ceil(float(centres[:, 1].max()) + radius)) + 1)
    if x0 >= x1 or y0 >= y1:
        return None
    weight = np.zeros((y1 - y0, x1 - x0), np.float64)
    for cx, cy in centres:
        sx0, sx1 = max(x0, int(math.floor(cx - radius))), min(x1, int(math.ceil(cx + radius)) + 1)
        sy0, sy1 = max(y0, int(math.floor(cy - radius))), min(y1, int(math.ceil(cy + radius)) + 1)
        if sx0 >= sx1 or sy0 >= sy1:
            continue
        dx = np.arange(sx0, sx1) + 0.5 - cx
        dy = np.arange(sy0, sy1) + 0.5 - cy
        r = np.sqrt(dy[:, None] * dy[:, None] + dx[None, :] * dx[None, :])
        stamp = falloff(r, radius, inner)
        window = weight[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0]
        np.maximum(window, stamp, out=window)
    return weight * strength, (y0, y1, x0, x1)


def falloff(r: np.ndarray, radius: float, inner: float) -> np.ndarray:
    """A stamp's weight at distance ``r``: 1 within ``inner``, 0 from ``radius`` on, a smoothstep between."""
    if radius - inner <= 1e-9:
        return (r < radius).astype(np.float64)
    t = np.clip((radius - r) / (radius - inner), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _brush(lab: np.ndarray, edit: dict, kind: str, origin: np.ndarray | None, offset: tuple[int, int]) -> np.ndarray:
    size = _number(edit, "size", 0.5, MAX_BRUSH_SIZE)
    hardness = _number(edit, "hardness", 0.0, 1.0, default=0.5)
    strength = _number(edit, "strength", 0.0, 1.0, default=1.0)
    centres = _centres(edit)
    if len(centres) * (size + 2.0) ** 2 > MAX_STROKE_WORK:
        raise PatternshopError(f"the stroke is too large ({len(centres)} stamps of {size:g} px); paint it in parts")
    target = None
    if kind == "density":
        mode = edit.get("mode", "darken")
        if mode not in ("darken", "lighten"):
            raise PatternshopError(f"mode must be darken or lighten, got {mode!r}")
    elif kind == "correlation":
        target = np.asarray(_ab(edit.get("ab")), np.float64)
    elif origin is None:
        raise PatternshopError("the eraser needs the opened map, and this project has none")
    out = lab.copy()
    found = stroke_weight(lab.shape[:2], centres, size, hardness, strength)
    if found is None:
        return out
    w, (y0, y1, x0, x1) = found
    if kind == "eraser":  # only where the opened map lies
        oy0, ox0 = offset[1], offset[0]
        y0c, y1c = max(y0, oy0), min(y1, oy0 + origin.shape[0])
        x0c, x1c = max(x0, ox0), min(x1, ox0 + origin.shape[1])
        if y0c >= y1c or x0c >= x1c:
            return out
        w = w[y0c - y0 : y1c - y0, x0c - x0 : x1c - x0]
        before = out[y0c:y1c, x0c:x1c].astype(np.float64)
        opened = origin[y0c - oy0 : y1c - oy0, x0c - ox0 : x1c - ox0].astype(np.float64)
        out[y0c:y1c, x0c:x1c] = before + w[..., None] * (opened - before)
        return out
    region = out[y0:y1, x0:x1]
    if kind == "density":
        L = region[..., 0].astype(np.float64)
        region[..., 0] = L * (1.0 - w) if edit.get("mode", "darken") == "darken" else L + w * (100.0 - L)
    else:
        ab = region[..., 1:].astype(np.float64)
        region[..., 1:] = ab + w[..., None] * (target - ab)
    return out


# --- the other edits ---------------------------------------------------------------------------------------
def _rect_mask(shape: tuple[int, int], rect: Any) -> np.ndarray:
    """Pixels whose centre lies in the rectangle [x0, y0, x1, y1] (map pixels, corners in any order;
    :func:`synthesis.edits.rect_region`)."""
    if not isinstance(rect, list) or len(rect) != 4:
        raise PatternshopError("rect is [x0, y0, x1, y1] in map pixels")
    (x0, y0), (x1, y1) = _pair(rect[:2], "rect"), _pair(rect[2:], "rect")
    (x0, x1), (y0, y1) = sorted((x0, x1)), sorted((y0, y1))
    if x0 == x1 or y0 == y1:  # a click without a drag selects nothing
        return np.zeros(shape, bool)
    side = float(max(shape))
    return rect_region(shape, (x0 / side, y0 / side, x1 / side, y1 / side)) > 0


def _polygon_mask(shape: tuple[int, int], polygon: Any) -> np.ndarray:
    """Pixels inside a lasso polygon [[x, y], ...] (map pixels; PIL's polygon fill at the pixel centres)."""
    from PIL import Image, ImageDraw

    if not isinstance(polygon, list) or not 3 <= len(polygon) <= MAX_STAMPS:
        raise PatternshopError(f"polygon is a list of 3 to {MAX_STAMPS} [x, y] vertices")
    vertices = [_pair(vertex, "polygon") for vertex in polygon]
    image = Image.new("1", (shape[1], shape[0]), 0)
    ImageDraw.Draw(image).polygon([(x - 0.5, y - 0.5) for x, y in vertices], fill=1, outline=1)
    return np.asarray(image, bool)


def _similar_mask(lab: np.ndarray, edit: dict) -> np.ndarray:
    """The magic wand: pixels within ``tolerance`` (CIELAB distance) of the seed pixel's colour, only those
    connected to it unless ``contiguous`` is false."""
    x, y = _pair(edit.get("seed"), "seed")
    height, width = lab.shape[:2]
    j, i = int(math.floor(x)), int(math.floor(y))
    if not (0 <= i < height and 0 <= j < width):
        raise PatternshopError(f"seed ({x:g}, {y:g}) lies outside the {width} x {height} px map")
    tolerance = _number(edit, "tolerance", 0.0, 400.0, default=10.0)
    distance = np.sqrt(np.sum((lab.astype(np.float64) - lab[i, j].astype(np.float64)) ** 2, axis=2))
    mask = distance <= tolerance
    if edit.get("contiguous", True):
        from scipy import ndimage

        labels, _ = ndimage.label(mask)
        mask = labels == labels[i, j]
    return mask


def _fill(lab: np.ndarray, edit: dict) -> tuple[np.ndarray, str]:
    """A selection (``rect``, lasso ``polygon``, or ``seed`` for similar colour) gets ``ab`` and/or ``density``."""
    ab = edit.get("ab")
    density = edit.get("density")
    if ab is None and density is None:
        raise PatternshopError("fill needs ab (a colour), density, or both")
    if "polygon" in edit:
        mask, label = _polygon_mask(lab.shape[:2], edit["polygon"]), "lasso fill"
    elif "seed" in edit:
        mask, label = _similar_mask(lab, edit), "similar-colour fill"
    elif "rect" in edit:
        mask, label = _rect_mask(lab.shape[:2], edit["rect"]), "fill"
    else:
        raise PatternshopError("fill needs a selection: rect [x0, y0, x1, y1], polygon [[x, y], ...] or seed [x, y]")
    out = lab.copy() if ab is None else np.array(set_correlation(LabMap(lab), _ab(ab), mask.astype(np.float32)).lab)
    if density is not None:
        out[mask, 0] = 100.0 * (1.0 - _number(edit, "density", 0.0, 1.0))
    return out, label


def _gradient(lab: np.ndarray, edit: dict) -> np.ndarray:
    side = float(max(lab.shape[:2]))
    start = _pair(edit.get("start"), "start")
    end = _pair(edit.get("end"), "end")
    values = _pair(edit.get("values", [1.0, 0.0]), "values", 0.0, 1.0)
    result = density_gradient(LabMap(lab), (start[0] / side, start[1] / side), (end[0] / side, end[1] / side), values)
    return np.array(result.lab)


def _expand(lab: np.ndarray, edit: dict, offset: tuple[int, int]) -> tuple[np.ndarray, tuple[int, int]]:
    margins = edit.get("margins")
    if not isinstance(margins, list) or len(margins) != 4:
        raise PatternshopError("expand needs margins: [left, top, right, bottom] in pixels")
    left, top, right, bottom = (int(_number({"margin": m}, "margin", 0, MAX_SIDE)) for m in margins)
    height, width = lab.shape[:2]
    if width + left + right > MAX_SIDE or height + top + bottom > MAX_SIDE:
        raise PatternshopError(f"the expanded map would be {width + left + right} x {height + top + bottom} px; "
                               f"the studio edits maps up to {MAX_SIDE} px a side")
    fill = edit.get("fill")
    if fill is not None and fill != "content-aware":
        if not isinstance(fill, list) or len(fill) != 3:
            raise PatternshopError("expand's fill is [L, a, b], \"content-aware\" (more of the map's texture) "
                                   "or null (repeat the edge pixels)")
        fill = (_number({"L": fill[0]}, "L", 0, 100), *_ab(fill[1:], "fill"))
    result = expand(LabMap(lab), (left, top, right, bottom), fill)
    return np.array(result.lab), (offset[0] + left, offset[1] + top)


def apply_edit(lab: np.ndarray, edit: Any, origin: np.ndarray | None = None,
               offset: tuple[int, int] = (0, 0)) -> EditResult:
    """The map ``lab`` (H, W, 3) after ``edit`` (a JSON object, see the module docstring).

    ``origin`` is the opened map and ``offset`` the (x, y) pixel of the current map where its top-left
    pixel lies (canvas expansion moves it); the eraser paints the opened map back.

    Raises:
        PatternshopError: an unknown type or a missing or bad field; the message says which.
    """
    if not isinstance(edit, dict):
        raise PatternshopError("an edit is a JSON object with a type")
    kind = edit.get("type")
    if kind not in EDIT_TYPES:
        raise PatternshopError(f"unknown edit type {kind!r}; types: {', '.join(EDIT_TYPES)}")
    new_offset = tuple(offset)
    if kind in ("density", "correlation", "eraser"):
        out = _brush(lab, edit, kind, origin, offset)
    elif kind == "fill":
        out, label = _fill(lab, edit)
    elif kind == "gradient":
        out = _gradient(lab, edit)
    else:
        out, new_offset = _expand(lab, edit, offset)
    out = np.ascontiguousarray(out, np.float32)
    np.clip(out[..., 0], 0.0, 100.0, out=out[..., 0])
    np.clip(out[..., 1:], -128.0, 127.0, out=out[..., 1:])
    if kind != "fill":
        label = LABELS[kind] + (f" ({edit.get('mode', 'darken')})" if kind == "density" else "")
    return EditResult(out, (int(new_offset[0]), int(new_offset[1])), label)
