"""Correlation analysis of one stationary point pattern: PCF, radial spectrum, palette colour."""

from __future__ import annotations

import math
import os
from collections.abc import Callable

import numpy as np

from synthesis.errors import PatternshopError
from synthesis.palette import OUTSIDE_CORPUS, Palette, hue_chroma
from synthesis.pcf import r_max, stationary_pcf
from synthesis.points import PointSet

MAX_SPECTRUM_BINS = 1024
SPECTRUM_REACH = 2.5  # the spectrum's bins reach this many times the mean point frequency sqrt(n)
MAX_SPECTRUM_POINTS = round((MAX_SPECTRUM_BINS / SPECTRUM_REACH) ** 2)  # 167,772: the bins reach that far for so many points
# rough shares of an analysis's time, for its progress bar
_STAGE_SHARES = {"coincident points": 10.0, "pair correlation": 84.0, "spectrum": 5.0, "palette colour": 1.0}

Progress = Callable[[float], None]  # called with the fraction of a stage done


def radial_spectrum(points: PointSet) -> tuple[np.ndarray, np.ndarray]:
    """Radial power spectrum of a centred square window of a pattern.

    The window is the largest centred square, shrunk for patterns of more than
    :data:`MAX_SPECTRUM_POINTS` points to about that many points' worth of area, so
    that the (at most :data:`MAX_SPECTRUM_BINS`) bins still reach 2.5 times the
    mean point frequency. This is sound for the stationary patterns analysed:
    every window has the same spectrum, and a periodogram's noise per frequency
    does not fall with more points (each power value is exponentially
    distributed whatever n); a larger window would only cut the bins off below
    the point frequency, and cost a transform of all its points.

    Returns frequencies (B,) in cycles per window side and power (B,) (1 for
    Poisson; the window is treated as periodic, so the lowest bins see some
    leakage). B covers 2.5 times the mean point frequency sqrt(n) of the window.
    """
    from synthesis.spectrum import RadialSpectrum

    w, h = points.domain
    side = min(w, h, math.sqrt(MAX_SPECTRUM_POINTS * w * h / max(len(points), 1)))
    lo = np.array([(w - side) / 2, (h - side) / 2])
    window = (points.xy - lo) / side
    window = window[np.all((window >= 0) & (window < 1), axis=1)]
    bins = min(MAX_SPECTRUM_BINS, int(SPECTRUM_REACH * math.sqrt(len(window))) + 2)
    power = RadialSpectrum(len(window), bins)(window)
    return np.arange(bins, dtype=np.float64), power


DEGENERATE_SHARE = 0.5  # a pattern with more than this share of (nearly) coincident points has no correlation to decode
COINCIDENT = 0.05  # in units of r_max (of the occupied area): the generators' clustered presets have up to 4 % of points this close, not 50 %


def coincident_points(points: PointSet, progress: Progress | None = None) -> int:
    """How many points have another closer than :data:`COINCIDENT` r_max.

    r_max is that of the area the points occupy (the cells, about one domain-wide
    r_max on a side, that hold a point), so that a pattern filling a small part of
    its domain (a stippled object on a large white canvas) is judged at its own
    spacing; piles of coincident points stay coincident at any scale. Only the points
    with a neighbour in the cells around them (:func:`_near_another`) are measured
    (:func:`_count_within`, ``progress(fraction)`` after each of its steps, so Ctrl+C
    is honoured at once). numpy only: ``infer`` runs this check and would pay numba's
    start (0.3 s), or scipy.spatial's import (0.1-0.2 s) for a k-d tree, for it.
    """
    n = len(points)
    if n < 2:
        return 0
    w, h = points.domain
    side = float(r_max(n, w * h))  # cells of one domain-wide r_max, clamped to the domain
    columns = math.ceil(w / side)
    cells = np.minimum(np.maximum(points.xy // side, 0), [columns - 1, math.ceil(h / side) - 1]).astype(np.int64)
    keys = cells[:, 1] * columns + cells[:, 0]  # one integer per cell: np.unique of rows took 8 times as long
    occupied = min(len(np.unique(keys)) * side * side, w * h)
    reach = COINCIDENT * float(r_max(n, occupied))
    return _count_within(points.xy[_near_another(points.xy, reach)], reach, progress)


def _count_within(xy: np.ndarray, reach: float, progress: Progress | None = None) -> int:
    """How many of the points (m, 2) have another closer than ``reach``, exactly.

    The points are binned in square cells of side ``reach / sqrt(2)`` (a hair less): two points in one cell are
    closer than ``reach``, so every point of a cell holding several counts at once (a pile of any size costs one
    pass). A point alone in its cell can only be that close to a point of the 24 cells around it (two cells each
    way), which are searched one offset at a time, only for the points not yet found (``progress`` after each
    offset). Each cell's points are compared with at most one lone point per offset, so the work stays linear in m.
    """
    if len(xy) < 2:
        if progress is not None:
            progress(1.0)
        return 0
    cells = np.floor(xy / (reach / math.sqrt(2.0) * (1.0 - 1e-9))).astype(np.int64)
    cells -= cells.min(axis=0) - 2  # two free rows and columns around: the offsets' keys stay distinct
    columns = int(cells[:, 0].max()) + 3
    keys = cells[:, 1] * columns + cells[:, 0]
    order = np.argsort(keys, kind="stable")
    keys, xy = keys[order], xy[order]
    occupied, first, counts = np.unique(keys, return_index=True, return_counts=True)
    found = np.repeat(counts > 1, counts)  # per point, in key order
    offsets = [dy * columns + dx for dy in range(-2, 3) for dx in range(-2, 3) if dx or dy]
    for step, offset in enumerate(offsets, 1):
        lone = np.flatnonzero(~found)
        target = keys[lone] + offset
        cell = np.minimum(np.searchsorted(occupied, target), len(occupied) - 1)
        hit = occupied[cell] == target
        lone, cell = lone[hit], cell[hit]
        pair_of = np.repeat(np.arange(len(lone)), counts[cell])  # every point of the cell, paired with its lone point
        other = np.arange(len(pair_of)) + np.repeat(first[cell] - (np.cumsum(counts[cell]) - counts[cell]), counts[cell])
        close = np.hypot(*(xy[lone[pair_of]] - xy[other]).T) < reach
        found[lone[pair_of[close]]] = True
        if progress is not None:
            progress(step / len(offsets))
    return int(np.count_nonzero(found))


def _near_another(xy: np.ndarray, reach: float) -> np.ndarray:
    """(n,) bool: the points (n, 2) with another point in their cell of side ``reach`` (a hair more, against
    rounding) or one of the 8 around it, the only ones that can have one closer than ``reach``:
    :func:`coincident_points` measures only those (the 40 ``bench/bench_infer.py`` stipplings: 0-2.5 % of their
    points; the whole check 10-14 -> 4-7 ms)."""
    cells = np.floor(xy / (reach * (1.0 + 1e-6))).astype(np.int64)
    cells -= cells.min(axis=0) - 1  # a free row and column around: neighbours' keys stay distinct
    columns = int(cells[:, 0].max()) + 2
    keys = cells[:, 1] * columns + cells[:, 0]
    occupied, cell_of, counts = np.unique(keys, return_inverse=True, return_counts=True)
    near = counts > 1
    for step in (1, columns - 1, columns, columns + 1):  # the neighbours after a cell; those before see it
        found = np.minimum(np.searchsorted(occupied, occupied + step), len(occupied) - 1)
        hit = occupied[found] == occupied + step
        near[hit] = True
        near[found[hit]] = True
    return near[cell_of]


def check_not_degenerate(points: PointSet, progress: Progress | None = None) -> None:
    """Refuse a degenerate pattern: more than :data:`DEGENERATE_SHARE` of its points within :data:`COINCIDENT`
    r_max of another (``analyze`` and ``infer`` alike: neither has a correlation to read from it).

    Raises:
        PatternshopError: naming how many points coincide.
    """
    coincident = coincident_points(points, progress)
    if coincident > DEGENERATE_SHARE * len(points):
        raise PatternshopError(
            f"{coincident} of {len(points)} points lie on top of another point (closer than {COINCIDENT} r_max): "
            "the pattern is degenerate and has no correlation colour to decode"
        )


def analyze_points(points: PointSet, palette: Palette, progress: bool = False) -> dict:
    """PCF, spectrum, decoded colour, its confidence and nearest preset of a stationary pattern (JSON-ready dict).

    ``exemplar_distance`` is how far the perceptually nearest palette exemplar
    is, in units of the corpus's own exemplar spacing (:class:`synthesis.palette.Decoded`);
    ``confidence`` names its band, and ``warning`` (present only then) says that
    the pattern lies outside the corpus, its colour being a guess. A degenerate
    pattern is an error (:func:`check_not_degenerate`): any colour decoded from it
    would be a confident answer to a question it cannot answer. ``progress``:
    a progress bar on stderr (tqdm). The work goes in blocks of a fraction of a
    second, so Ctrl+C stops it at once.
    """
    from tqdm import tqdm

    from synthesis.kernels import announce_compilation

    announce_compilation(("synthesis.cells",), "analysis kernels", seconds=5)
    w, h = points.domain
    with tqdm(total=100.0, desc="analyze", disable=not progress, leave=False,
              bar_format="{desc}{percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]") as bar:
        offsets = dict(zip(_STAGE_SHARES, np.cumsum([0.0, *_STAGE_SHARES.values()])))

        def stage(name: str) -> Progress:
            """Start stage ``name`` (its label, the bar at its start); returns its progress callback."""
            bar.set_description(f"analyze: {name}")

            def advance(fraction: float) -> None:
                bar.update(offsets[name] + _STAGE_SHARES[name] * fraction - bar.n)

            advance(0.0)
            return advance

        check_not_degenerate(points, stage("coincident points"))
        radii = palette.radii  # the PCF the palette decodes (pcf_radii())
        pcf = stationary_pcf(points.xy, points.domain, periodic=False, radii=radii, progress=stage("pair correlation"))
        stage("spectrum")
        frequency, power = radial_spectrum(points)
        stage("palette colour")
        decoded = palette.locate_pcf(pcf)  # the PCF just measured: the colour does not depend on orientation
        bar.update(bar.total - bar.n)
    a, b = decoded.a, decoded.b
    hue, chroma = hue_chroma(a, b)
    warning = {} if decoded.confidence != "outside the corpus" else {"warning": (
        f"the pattern lies outside the palette's corpus (nearest exemplar {decoded.exemplar_distance:.1f} exemplar spacings away, "
        f"beyond {OUTSIDE_CORPUS:g}): its colour is the nearest guess, not a match")}
    return {
        "n": len(points),
        "domain": [w, h],
        "a": round(a, 3),
        "b": round(b, 3),
        "hue": round(hue, 2),
        "chroma": round(chroma, 2),
        "nearest_preset": palette.nearest_preset(a, b),
        "exemplar_distance": round(decoded.exemplar_distance, 3),
        "confidence": decoded.confidence,
        **warning,
        "r_max": r_max(len(points), w * h),
        "r": radii.round(6).tolist(),
        "pcf": pcf.round(6).tolist(),
        "frequency": frequency.tolist(),
        "spectrum": power.round(6).tolist(),
    }


def plot_analysis(result: dict, path: str | os.PathLike) -> None:
    """Write a PNG with the PCF and the radial spectrum of an :func:`analyze_points` result."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from synthesis.atomic import atomic_path
    from synthesis.labmap import LabMap

    swatch = LabMap(np.array([[[70.0, result["a"], result["b"]]]])).to_srgb()[0, 0]
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    left.plot(result["r"], result["pcf"], color=swatch, linewidth=2.5)
    left.axhline(1.0, color="grey", linewidth=0.8, linestyle="--")
    left.set(xlabel="r / r_max", ylabel="g(r)", title="pair correlation function")
    right.plot(result["frequency"][1:], result["spectrum"][1:], color=swatch, linewidth=1.5)
    right.axhline(1.0, color="grey", linewidth=0.8, linestyle="--")
    right.set(xlabel="frequency (cycles per window side)", ylabel="power", title="radial power spectrum")
    figure.suptitle(
        f"n = {result['n']}   palette colour a = {result['a']:.1f}, b = {result['b']:.1f}   "
        f"nearest preset: {result['nearest_preset']}"
    )
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png", dpi=100)
    plt.close(figure)
