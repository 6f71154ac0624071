"""Rendering point patterns: anti-aliased dot rasters, PNG and SVG outputs (SPEC.md section 3).

Points live in the domain ``[0, w] x [0, h]`` (``max(w, h) = 1``), origin at
the top-left, y down, exactly as in images and SVG, so no axis is flipped. A
dot is a filled disk of the point's radius (``PointSet.radius``, in domain
units) or, for points without radii, of :func:`default_radius`.

* :func:`rasterize_dots`: (H, W) ink coverage in [0, 1], the basis of the rest.
* :func:`render_png`: black dots on white, 8-bit greyscale PNG.
* :func:`write_svg`: one ``<circle>`` per point in millimetres, for browsers
  and pen-plotter tools (vpype, Inkscape); filled or, with a pen width, outlined.
* :func:`tone_image`: the coverage blurred by a Gaussian, the tone an eye sees
  from a distance, for comparing a stipple with a density map.

All files are written atomically (:mod:`synthesis.atomic`).
"""

from __future__ import annotations

import math
import os
from numbers import Integral, Real

import numpy as np
from PIL import Image

from synthesis.atomic import atomic_path, atomic_write_text
from synthesis.errors import PatternshopError
from synthesis.points import PointSet

PathLike = str | os.PathLike

DEFAULT_RADIUS_FACTOR = 0.3  # default dot radius as a fraction of the mean point spacing sqrt(w h / n)
SVG_NAMESPACE = "http://www.w3.org/2000/svg"
_ROWS_PER_CHUNK = 1 << 21  # (point, sample row) spans handled at once; bounds the temporary memory


def default_radius(points: PointSet) -> float:
    """Dot radius (domain units) for points without radii: 0.3 x the mean spacing sqrt(w h / n).

    An empty set gets the radius of a single point (0.3 sqrt(w h)).
    """
    w, h = points.domain
    return DEFAULT_RADIUS_FACTOR * math.sqrt(w * h / max(len(points), 1))


def dot_radii(points: PointSet) -> np.ndarray:
    """(n,) float64 dot radii in domain units: ``points.radius``, or :func:`default_radius` for all.

    Raises:
        PatternshopError: non-finite positions, or non-finite or negative radii.
    """
    if not np.all(np.isfinite(points.xy)):
        raise PatternshopError("cannot render points with non-finite coordinates")
    if points.radius is None:
        return np.full(len(points), default_radius(points))
    radius = points.radius
    if not np.all(np.isfinite(radius)) or np.any(radius < 0):
        raise PatternshopError("dot radii must be finite and non-negative")
    return radius


def raster_size(points: PointSet, width_px: int) -> tuple[int, int]:
    """(H, W) pixel size of a raster ``width_px`` wide in the domain's aspect ratio: H = round(W h / w) >= 1."""
    _check_count("width_px", width_px)
    w, h = points.domain
    return max(1, round(width_px * h / w)), int(width_px)


def rasterize_dots(points: PointSet, width_px: int, supersample: int = 4) -> np.ndarray:
    """Anti-aliased ink coverage of the points' dots.

    Each dot is a filled disk; a pixel's value is the fraction of its
    ``supersample x supersample`` sample points (at sub-pixel centres) inside
    any disk, so overlapping dots form their union (coverage never exceeds 1).
    One scale, ``W / w`` pixels per domain unit, is used on both axes so disks
    stay round; pixel (i, j) covers ``[j, j + 1] x [i, i + 1] / (W / w)`` (y down).

    Args:
        points: the pattern; dots of ``points.radius`` or :func:`default_radius`.
        width_px: W, the raster width in pixels (>= 1).
        supersample: samples per pixel along each axis (>= 1).

    Returns:
        (H, W) float32 coverage in [0, 1], 1 = fully inked; H = round(W h / w).

    Raises:
        PatternshopError: ``width_px < 1`` or ``supersample < 1``, bad coordinates or radii.
    """
    height, width = raster_size(points, width_px)
    _check_count("supersample", supersample)
    s = int(supersample)
    rows, cols = height * s, width * s
    scale = cols / points.domain[0]  # samples per domain unit
    radius = dot_radii(points) * scale
    # spans of covered samples, one per (point, sample row), accumulated as +1 at the
    # first and -1 after the last sample of each row; a running sum then counts the
    # dots covering each sample
    diff = np.zeros(rows * (cols + 1), dtype=np.int32)
    keep = np.flatnonzero(radius > 0)
    keep = keep[np.argsort(points.xy[keep, 1], kind="stable")]  # top to bottom: nearby memory writes
    px, py, radius = points.xy[keep, 0] * scale, points.xy[keep, 1] * scale, radius[keep]
    # sample row i (centre i + 1/2) meets the open disk where |i + 1/2 - py| < r
    first = np.clip(np.floor(py - radius - 0.5) + 1, 0, rows)
    last = np.clip(np.ceil(py + radius - 0.5) - 1, -1, rows - 1)
    count = np.maximum(last - first + 1, 0).astype(np.int64)
    ends = np.cumsum(count)
    for lo, hi in _chunks(ends, _ROWS_PER_CHUNK):
        _add_spans(diff, cols, px[lo:hi], py[lo:hi], radius[lo:hi], first[lo:hi].astype(np.int64), count[lo:hi])
    covered = np.cumsum(diff.reshape(rows, cols + 1)[:, :cols], axis=1, dtype=np.int32) > 0
    return covered.reshape(height, s, width, s).mean(axis=(1, 3), dtype=np.float32)


def _chunks(ends: np.ndarray, budget: int) -> list[tuple[int, int]]:
    """Split points into consecutive runs [lo, hi) of about ``budget`` rows each; ``ends`` = cumulative row counts."""
    bounds = [0]
    while bounds[-1] < len(ends):
        done = ends[bounds[-1] - 1] if bounds[-1] else 0
        bounds.append(max(int(np.searchsorted(ends, done + budget, side="right")), bounds[-1] + 1))
    return list(zip(bounds[:-1], bounds[1:]))


def _add_spans(
    diff: np.ndarray, cols: int, px: np.ndarray, py: np.ndarray, radius: np.ndarray, first: np.ndarray, count: np.ndarray
) -> None:
    """Add the row spans of some disks (sample units) to the flat (rows, cols + 1) difference array."""
    owner = np.repeat(np.arange(len(count)), count)
    offsets = np.cumsum(count) - count
    row = first[owner] + (np.arange(len(owner)) - offsets[owner])
    dy = row + 0.5 - py[owner]
    half = np.sqrt(np.maximum(radius[owner] ** 2 - dy**2, 0.0))
    x = px[owner]
    # sample column j (centre j + 1/2) is inside where |j + 1/2 - px| < half
    start = np.clip(np.floor(x - half - 0.5) + 1, 0, cols).astype(np.int64)
    stop = np.clip(np.ceil(x + half - 0.5), 0, cols).astype(np.int64)  # one past the last sample
    hit = start < stop
    base = row[hit] * (cols + 1)
    np.add.at(diff, base + start[hit], 1)
    np.add.at(diff, base + stop[hit], -1)


def render_png(points: PointSet, path: PathLike, width_px: int = 1024, supersample: int = 4) -> None:
    """Write the dots black on white as an 8-bit greyscale PNG, ``width_px`` wide (atomically).

    Grey level = round(255 (1 - coverage)) of :func:`rasterize_dots`.
    """
    with atomic_path(path) as tmp:
        Image.fromarray(dots_grey(points, width_px, supersample)).save(tmp, format="PNG")  # uint8 (H, W): mode "L"


def dots_grey(points: PointSet, width_px: int, supersample: int = 4) -> np.ndarray:
    """(H, W) uint8 dots black on white: round(255 (1 - coverage)) of :func:`rasterize_dots`."""
    return np.rint(255.0 * (1.0 - rasterize_dots(points, width_px, supersample))).astype(np.uint8)


def write_svg(
    points: PointSet,
    path: PathLike,
    width_mm: float = 200.0,
    pen_width_mm: float | None = None,
    min_radius_mm: float = 0.0,
    max_radius_mm: float | None = None,
) -> None:
    """Write the dots as an SVG of circles (atomically), sized in millimetres.

    The document is ``width_mm`` x ``width_mm h / w`` mm with a viewBox in the
    same millimetres, so user units are mm and the domain point (x, y) lands at
    (x, y) * width_mm / w. Circles are filled black; with ``pen_width_mm`` they are
    outlines of that stroke width instead (for pen plotters), with radii at least
    half the pen width. Radii are then clamped into [min_radius_mm, max_radius_mm].
    Numbers carry at most 4 decimals.

    Raises:
        PatternshopError: a non-positive or non-finite size or pen width, a negative
            minimum radius, or a maximum radius below the minimum (or below half the pen).
    """
    _check_positive("width_mm", width_mm)
    if pen_width_mm is not None:
        _check_positive("pen_width_mm", pen_width_mm)
    if not (isinstance(min_radius_mm, Real) and math.isfinite(min_radius_mm) and min_radius_mm >= 0):
        raise PatternshopError(f"min_radius_mm must be a finite number >= 0, got {min_radius_mm!r}")
    lower = max(float(min_radius_mm), pen_width_mm / 2 if pen_width_mm is not None else 0.0)
    upper = math.inf if max_radius_mm is None else max_radius_mm
    if not (isinstance(upper, Real) and not math.isnan(upper)) or upper < lower:
        what = f"half the pen width ({lower:g} mm)" if lower > min_radius_mm else f"min_radius_mm ({lower:g})"
        raise PatternshopError(f"max_radius_mm ({max_radius_mm!r}) must not be below {what}")

    w, h = points.domain
    mm_per_unit = width_mm / w
    radius = np.clip(dot_radii(points) * mm_per_unit, lower, upper)
    xy = points.xy * mm_per_unit
    if pen_width_mm is None:
        style = 'fill="black"'
    else:
        style = f'fill="none" stroke="black" stroke-width="{_number(pen_width_mm)}"'
    width, height = _number(width_mm), _number(width_mm * h / w)
    circles = [
        f'<circle cx="{_number(x)}" cy="{_number(y)}" r="{_number(r)}"/>' for (x, y), r in zip(xy.tolist(), radius.tolist())
    ]
    document = "\n".join(
        [
            '<?xml version="1.0" encoding="UTF-8"?>',
            f'<svg xmlns="{SVG_NAMESPACE}" version="1.1" width="{width}mm" height="{height}mm" viewBox="0 0 {width} {height}">',
            f"<desc>Patternshop: {len(circles)} points; domain {w:.6g} x {h:.6g}; 1 user unit = 1 mm</desc>",
            f"<g {style}>",
            *circles,
            "</g>",
            "</svg>",
            "",
        ]
    )
    atomic_write_text(path, document)


def tone_image(points: PointSet, width_px: int, blur_px: float) -> np.ndarray:
    """Perceived tone: :func:`rasterize_dots` blurred by a Gaussian (std ``blur_px`` pixels, edges 'nearest').

    Returns:
        (H, W) float32 in [0, 1], 1 = black, comparable with a density map ``1 - L/100``.
    """
    if not (isinstance(blur_px, Real) and math.isfinite(blur_px) and blur_px >= 0):
        raise PatternshopError(f"blur_px must be a finite number >= 0, got {blur_px!r}")
    coverage = rasterize_dots(points, width_px)
    from scipy.ndimage import gaussian_filter  # only here: scipy.ndimage takes 0.2 s to import

    return gaussian_filter(coverage, sigma=float(blur_px), mode="nearest")


def _check_count(name: str, value: int) -> None:
    """A positive integer argument (bool excluded)."""
    if isinstance(value, bool) or not isinstance(value, Integral) or value < 1:
        raise PatternshopError(f"{name} must be an integer >= 1, got {value!r}")


def _check_positive(name: str, value: float) -> None:
    """A finite number > 0."""
    if isinstance(value, bool) or not isinstance(value, Real) or not (math.isfinite(value) and value > 0):
        raise PatternshopError(f"{name} must be a finite number > 0, got {value!r}")


def _number(value: float) -> str:
    """``value`` with at most 4 decimals, trailing zeros dropped (``12.5``, ``3``, never ``-0``)."""
    text = f"{value:.4f}".rstrip("0").rstrip(".")
    return "0" if text == "-0" else text
