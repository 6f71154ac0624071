"""Correlation analysis of one stationary point pattern: PCF, radial spectrum, palette colour."""

from __future__ import annotations

import math
import os

import numpy as np

from synthesis.errors import PatternshopError
from synthesis.palette import OUTSIDE_CORPUS, Palette, hue_chroma
from synthesis.pcf import pcf_radii, r_max, stationary_pcf
from synthesis.points import PointSet

MAX_SPECTRUM_BINS = 1024


def radial_spectrum(points: PointSet) -> tuple[np.ndarray, np.ndarray]:
    """Radial power spectrum of the largest centred square window of a pattern.

    Returns frequencies (B,) in cycles per window side and power (B,) (1 for
    Poisson; the window is treated as periodic, so the lowest bins see some
    leakage). B covers 2.5 times the mean point frequency sqrt(n).
    """
    from synthesis.spectrum import RadialSpectrum

    w, h = points.domain
    side = min(w, h)
    lo = np.array([(w - side) / 2, (h - side) / 2])
    window = (points.xy - lo) / side
    window = window[np.all((window >= 0) & (window < 1), axis=1)]
    bins = min(MAX_SPECTRUM_BINS, int(2.5 * math.sqrt(len(window))) + 2)
    power = RadialSpectrum(len(window), bins)(window)
    return np.arange(bins, dtype=np.float64), power


DEGENERATE_SHARE = 0.5  # a pattern with more than this share of (nearly) coincident points has no correlation to decode
COINCIDENT = 0.05  # in units of r_max: the generators' clustered presets have 4 % of points this close, not 50 %


def analyze_points(points: PointSet, palette: Palette) -> dict:
    """PCF, spectrum, decoded colour, its confidence and nearest preset of a stationary pattern (JSON-ready dict).

    ``exemplar_distance`` is how far the perceptually nearest palette exemplar
    is, in units of the corpus's own exemplar spacing (:class:`synthesis.palette.Decoded`);
    ``confidence`` names its band, and ``warning`` (present only then) says that
    the pattern lies outside the corpus, its colour being a guess. A degenerate pattern (more than :data:`DEGENERATE_SHARE` of its points within
    :data:`COINCIDENT` r_max of another) is an error: any colour decoded from it
    would be a confident answer to a question it cannot answer.
    """
    from scipy.spatial import cKDTree

    w, h = points.domain
    if len(points) >= 2:
        distance, _ = cKDTree(points.xy).query(points.xy, k=2)
        coincident = int(np.sum(distance[:, 1] < COINCIDENT * r_max(len(points), w * h)))
        if coincident > DEGENERATE_SHARE * len(points):
            raise PatternshopError(
                f"{coincident} of {len(points)} points lie on top of another point (closer than {COINCIDENT} r_max): "
                "the pattern is degenerate and has no correlation colour to decode"
            )
    radii = pcf_radii()
    pcf = stationary_pcf(points.xy, points.domain, periodic=False, radii=radii)
    frequency, power = radial_spectrum(points)
    decoded = palette.locate(points.xy, points.domain)
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
