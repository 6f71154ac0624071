"""Non-learned estimates the network is measured against, and the validation metrics.

* Density: kernel density estimation, a Gaussian blur of the point-count raster
  divided by the expected count of a fully black pixel (``points_per_ink / S^2``
  on the unit square). Its bandwidth is picked per dataset, the best of
  :data:`KDE_BANDWIDTHS` on the evaluated pairs (an oracle choice, so the
  baseline is as strong as it can be).
* Correlation: the map is cut into ``cells`` x ``cells`` squares; each square's
  points (the square grown until it holds :data:`MIN_WINDOW_POINTS`) are
  decoded by the palette in perceptual-feature space
  (:meth:`synthesis.palette.Palette.decode`, as ``patternshop analyze`` does:
  inverse-distance weighting of the nearest exemplars' latents) and the square
  takes that latent.

Metrics, on maps in the network's units (L/100 and z, all in [0, 1]):
``density_mae`` is the mean |density error| over all pixels; ``latent_mae``
is the mean |z error| (both channels) over the pixels whose true density is
at least :data:`LATENT_MIN_DENSITY` — where there are no points, correlation
is not observable and any value is as good as another.
:func:`latent_error_by_edge_distance` splits the same error by the distance to
the target's nearest correlation edge, in ab units: a reading that bleeds one
region's colour into its neighbour's shows as a large error near the edges.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.ndimage import distance_transform_edt, gaussian_filter

from data_gen.shards import Pairs
from synthesis.errors import PatternshopError
from synthesis.palette import Palette, ab_to_latent
from synthesis.raster import point_raster

KDE_BANDWIDTHS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0)  # pixels of the raster
MIN_WINDOW_POINTS = 128  # fewest points the perceptual decoder is given
LATENT_MIN_DENSITY = 0.1
EDGE_JUMP_AB = 6.0  # a correlation edge: neighbouring target pixels whose |da| + |db| exceeds this (ab units)
EDGE_DISTANCE_BINS_PX = (0, 4, 8, 16, 32)  # lower ends of the distance bins (map pixels); the last is open


def inked(target_l: np.ndarray) -> np.ndarray:
    """Where correlation is observable: true density 1 - L >= :data:`LATENT_MIN_DENSITY`, for the target's L channel
    (any shape, L/100 in [0, 1]; a numpy array or a torch tensor, answered in kind)."""
    return (1.0 - target_l) >= LATENT_MIN_DENSITY


def density_mae(predicted: np.ndarray, target: np.ndarray) -> float:
    """Mean |error| of density = 1 - channel 0, maps (..., 3, H, W) in [0, 1]."""
    return float(np.mean(np.abs(np.asarray(predicted)[..., 0, :, :] - np.asarray(target)[..., 0, :, :])))


def latent_mae(predicted: np.ndarray, target: np.ndarray) -> float:
    """Mean |latent error| over pixels with true density >= LATENT_MIN_DENSITY; maps (..., 3, H, W) in [0, 1]."""
    predicted, target = np.asarray(predicted), np.asarray(target)
    observable = inked(target[..., 0, :, :])
    error = np.abs(predicted[..., 1:, :, :] - target[..., 1:, :, :]).mean(axis=-3)
    return float(error[observable].mean()) if observable.any() else float("nan")


def correlation_edge_distance(target_latent: np.ndarray) -> np.ndarray:
    """(H, W) distance in pixels from each pixel to the nearest correlation edge of a target latent map (2, H, W) in
    [0, 1] (an edge lies between two 4-neighbours whose |da| + |db| exceeds :data:`EDGE_JUMP_AB`); inf without edges."""
    ab = 255.0 * np.asarray(target_latent, np.float64)
    jump = np.zeros(ab.shape[1:], bool)
    horizontal = np.abs(np.diff(ab, axis=2)).sum(0) > EDGE_JUMP_AB
    vertical = np.abs(np.diff(ab, axis=1)).sum(0) > EDGE_JUMP_AB
    jump[:, 1:] |= horizontal
    jump[:, :-1] |= horizontal
    jump[1:, :] |= vertical
    jump[:-1, :] |= vertical
    return distance_transform_edt(~jump) if jump.any() else np.full(jump.shape, np.inf)


def latent_error_by_edge_distance(predicted: np.ndarray, target: np.ndarray) -> list[dict]:
    """Mean a, b error (Euclidean, ab units) by distance to the target's nearest correlation edge, over the pixels
    :func:`latent_mae` counts; maps (K, 3, H, W) in [0, 1]. One row per bin of :data:`EDGE_DISTANCE_BINS_PX`:
    ``from_px``, ``to_px`` (None: open), ``pixels``, ``mean_ab_error`` (None for an empty bin)."""
    predicted, target = np.asarray(predicted, np.float64), np.asarray(target, np.float64)
    distances = np.stack([correlation_edge_distance(t[1:]) for t in target])
    errors = 255.0 * np.linalg.norm(predicted[:, 1:] - target[:, 1:], axis=1)
    observable = inked(target[:, 0])
    rows = []
    for low, high in zip(EDGE_DISTANCE_BINS_PX, (*EDGE_DISTANCE_BINS_PX[1:], None), strict=True):
        chosen = observable & (distances >= low) & (distances < (np.inf if high is None else high))
        rows.append({"from_px": low, "to_px": high, "pixels": int(chosen.sum()),
                     "mean_ab_error": round(float(errors[chosen].mean()), 2) if chosen.any() else None})
    return rows


def count_raster(xy_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) points per pixel, splatted bilinearly (sums kept), of points (n, 2) in map pixel coordinates."""
    side = max(shape)
    return point_raster(np.asarray(xy_px, np.float64) / side, side, clip=False)[:shape[0], :shape[1]].astype(np.float64)


def kde_density(raster: np.ndarray, points_per_ink: float, bandwidth_px: float) -> np.ndarray:
    """(H, W) density in [0, 1] from a point-count raster (H, W) of a domain whose long side is 1 (the unit square: S, S)."""
    side = max(raster.shape[-2:])
    blurred = gaussian_filter(np.asarray(raster, np.float64), bandwidth_px, mode="constant")
    return np.clip(blurred * side * side / points_per_ink, 0.0, 1.0)


def windowed_latent(points: np.ndarray, size: int, palette: Palette, cells: int = 4) -> np.ndarray:
    """(size, size, 2) latent field decoded per square cell from points (n, 2) in the unit square."""
    points = np.asarray(points, np.float64)
    field = np.empty((size, size, 2), np.float32)
    fallback = palette.exemplar_z.mean(axis=0)
    edges = np.linspace(0, size, cells + 1).round().astype(int)
    for row in range(cells):
        for col in range(cells):
            lo = np.array([edges[col], edges[row]]) / size
            hi = np.array([edges[col + 1], edges[row + 1]]) / size
            field[edges[row] : edges[row + 1], edges[col] : edges[col + 1]] = _decode_window(points, lo, hi, palette, fallback)
    return field


def _decode_window(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, palette: Palette, fallback: np.ndarray) -> np.ndarray:
    """Latent (2,) of the points in [lo, hi], the window grown about its centre until it holds enough points."""
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    while True:
        low, high = np.clip(centre - half, 0, 1), np.clip(centre + half, 0, 1)
        inside = points[np.all((points >= low) & (points <= high), axis=1)]
        if len(inside) >= MIN_WINDOW_POINTS:
            break
        if np.all(low == 0) and np.all(high == 1):
            return fallback
        half = half * 1.5
    try:
        a, b = palette.decode(inside - low, tuple(high - low))
    except PatternshopError:  # a thin border window whose rasters are too small to measure
        return fallback
    return ab_to_latent(np.array([a, b]))


def evaluate_baselines(rasters: np.ndarray, points: list[np.ndarray], targets: np.ndarray, points_per_ink: float,
                       palette: Palette, cells: int = 4) -> dict:
    """Baseline metrics on pairs: rasters (K, S, S), points K x (n, 2), targets (K, 3, S, S) in [0, 1].

    Returns ``kde_density_mae`` (at the best bandwidth, also returned as
    ``kde_bandwidth_px``), ``baseline_latent_mae`` and ``pairs``.
    """
    rasters = np.asarray(rasters, np.float64)
    true_density = 1.0 - np.asarray(targets)[:, 0]
    errors = {h: float(np.mean([np.abs(kde_density(r, points_per_ink, h) - d).mean() for r, d in zip(rasters, true_density, strict=True)]))
              for h in KDE_BANDWIDTHS}
    best = min(errors, key=errors.get)
    latents = np.stack([windowed_latent(xy, np.shape(targets)[-1], palette, cells).transpose(2, 0, 1) for xy in points])
    predicted = np.concatenate([np.asarray(targets)[:, :1], latents], axis=1)
    return {"kde_density_mae": round(errors[best], 5), "kde_bandwidth_px": best,
            "baseline_latent_mae": round(latent_mae(predicted, targets), 5), "pairs": len(rasters)}


def cached_baselines(folder: str | Path, pairs: Pairs, positions: np.ndarray, cells: int = 4) -> dict:
    """:func:`evaluate_baselines` on ``pairs[positions]`` of a pair folder, cached in ``<folder>/baselines.json``.

    The points per ink and the palette come from the folder's manifest; the
    cache is keyed by the items, ``cells`` and the folder's config key (the
    baselines never change for the same pairs).
    """
    import json

    from data_gen.shards import read_manifest
    from data_gen.storage import as_path, write_text_atomic
    from synthesis.palette import load_palette

    folder = as_path(folder)
    manifest = read_manifest(folder) or {}
    settings = manifest.get("settings", {})
    positions = np.asarray(positions)
    key = {"items": [int(i) for i in pairs.item[positions]], "cells": cells, "config_key": manifest.get("config_key")}
    cache = folder / "baselines.json"
    if cache.is_file():
        cached = json.loads(cache.read_text())
        if cached.get("key") == key:
            return cached["metrics"]
    targets = pairs.target[positions].transpose(0, 3, 1, 2).astype(np.float32) / 255.0
    metrics = evaluate_baselines(pairs.raster[positions], [pairs.points_of(int(k)) for k in positions], targets,
                                 float(settings.get("points_per_ink", 8000)), load_palette(settings.get("palette")), cells)
    write_text_atomic(cache, json.dumps({"key": key, "metrics": metrics}, indent=2) + "\n")
    return metrics
