"""The 2D perceptual embedding: MDS layout, orientation, IDW encoding, quality metrics.

Pure functions on arrays; :mod:`data_gen.palette` strings them together.
"""

from __future__ import annotations

import math

import numpy as np
import torch


def l1_distances(features: np.ndarray, chunk: int = 64) -> np.ndarray:
    """(N, N) float64 L1 distances between the rows of ``features`` (N, D)."""
    x = torch.from_numpy(np.ascontiguousarray(features, np.float32))
    out = np.empty((len(x), len(x)))
    for start in range(0, len(x), chunk):
        out[start : start + chunk] = torch.cdist(x[start : start + chunk], x, p=1).double().numpy()
    np.fill_diagonal(out, 0.0)
    return (out + out.T) / 2.0


def mds_layout(dissimilarity: np.ndarray, seed: int, inits: int = 4, max_iter: int = 300) -> np.ndarray:
    """(N, 2) metric MDS (SMACOF) layout of a precomputed dissimilarity matrix.

    SMACOF minimises the same raw stress as the paper's eq. 3 but decreases it
    monotonically, and it is deterministic for ``seed``; the best of ``inits``
    random starts is kept.
    """
    from sklearn.manifold import MDS

    mds = MDS(
        n_components=2, metric_mds=True, metric="precomputed", n_init=inits, init="random",
        max_iter=max_iter, random_state=seed, normalized_stress=False, eps=1e-6,
    )
    return mds.fit_transform(dissimilarity)


def stress1(dissimilarity: np.ndarray, layout: np.ndarray) -> float:
    """Kruskal's stress-1 of a layout, with the optimal global scale of the layout."""
    upper = np.triu_indices(len(layout), 1)
    target = dissimilarity[upper]
    distance = np.linalg.norm(layout[:, None] - layout[None], axis=-1)[upper]
    scale = float(target @ distance / (distance @ distance))
    return float(np.sqrt(np.sum((target - scale * distance) ** 2) / np.sum(target**2)))


def trustworthiness(dissimilarity: np.ndarray, layout: np.ndarray, k: int = 10) -> float:
    """Neighbourhood trustworthiness (Venna & Kaski) of the layout, in [0, 1]."""
    from sklearn.manifold import trustworthiness as sk_trustworthiness

    return float(sk_trustworthiness(dissimilarity, layout, n_neighbors=k, metric="precomputed"))


def orient(
    layout: np.ndarray, anchors: dict[str, np.ndarray], hues: dict[str, float], blue_window: float = 40.0,
    min_blue_chroma: float = 30.0,
) -> tuple[np.ndarray, dict]:
    """Rotate, reflect and normalise a layout into [0, 1]^2 so anchors land on their hues.

    Every rotation (1 degree steps) with and without a reflection is followed
    by a per-axis min-max normalisation to [0, 1]^2 (so the palette fills the
    ab square even when the layout is elongated); among those that put
    ``anchors["blue"]`` within ``blue_window`` degrees of ``hues["blue"]`` with
    chroma >= ``min_blue_chroma``, the one with the smallest summed hue error
    of all anchors wins (falling back to all candidates if none qualifies).

    Args:
        layout: (N, 2) MDS coordinates.
        anchors: name -> (2,) MDS coordinates of a reference pattern (needs "blue").
        hues: name -> wanted hue angle in degrees (atan2(b, a)).

    Returns:
        (N, 2) latent z, and a record of the transform (matrix, reflected, offset, scale).
    """
    centre = layout.mean(axis=0)
    names = list(hues)
    points = np.stack([anchors[name] for name in names]) - centre
    wanted = np.array([hues[name] for name in names])
    blue = names.index("blue")
    best = None
    for reflect in (False, True):
        flip = np.diag([1.0, -1.0]) if reflect else np.eye(2)
        for degrees in range(360):
            turn = math.radians(degrees)
            matrix = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]]) @ flip
            moved = (layout - centre) @ matrix.T
            low, span = moved.min(axis=0), np.ptp(moved, axis=0)
            ab = 255.0 * ((points @ matrix.T - low) / span) - 128.0
            hue = np.degrees(np.arctan2(ab[:, 1], ab[:, 0]))
            error = np.abs((hue - wanted + 180.0) % 360.0 - 180.0)
            qualifies = error[blue] <= blue_window and np.hypot(*ab[blue]) >= min_blue_chroma
            key = (not qualifies, float(error.sum()))
            if best is None or key < best[0]:
                best = (key, reflect, matrix, low, span)
    _, reflected, matrix, low, span = best
    z = ((layout - centre) @ matrix.T - low) / span
    record = {"centre": centre.tolist(), "matrix": matrix.tolist(), "reflected": bool(reflected),
              "offset": low.tolist(), "scale": (1.0 / span).tolist()}
    return z, record


def kde_locality(query: np.ndarray, exemplars: np.ndarray, window: float, low: float, high: float) -> np.ndarray:
    """IDW exponent phi(z) (Q,) from a Gaussian kernel density estimate of the exemplars.

    The density (Parzen window ``window``) is divided by its 90th percentile over
    the exemplars themselves, clamped to [0, 1] and scaled linearly to
    [low, high]: sparse regions interpolate smoothly, dense ones locally.
    """

    def density(points: np.ndarray) -> np.ndarray:
        out = np.empty(len(points))
        for start in range(0, len(points), 4096):
            d2 = np.sum((points[start : start + 4096, None] - exemplars[None]) ** 2, axis=-1)
            out[start : start + 4096] = np.exp(-d2 / (2 * window**2)).sum(axis=1)
        return out / (len(exemplars) * 2 * math.pi * window**2)

    reference = np.percentile(density(exemplars), 90)
    return low + (high - low) * np.clip(density(query) / reference, 0.0, 1.0)


EXACT_HIT = 1e-9  # latent distance at which a query is an exemplar


def idw_encode(query: np.ndarray, exemplars: np.ndarray, values: np.ndarray, power: np.ndarray) -> np.ndarray:
    """Inverse-distance weighting (paper eq. 4): (Q, 2) queries -> (Q, m) interpolated values.

    ``w_i = 1 / max(||z - z_i||^phi(z), 1e-10)``, weights normalised per query.
    A query that coincides with exemplars (distance < :data:`EXACT_HIT`) takes
    their value: the paper's clamp alone would let neighbours within
    ``1e-10^(1/phi)`` (0.02 at phi = 6) outweigh an exemplar sitting exactly there.
    """
    out = np.empty((len(query), values.shape[1]))
    for start in range(0, len(query), 4096):
        block = slice(start, start + 4096)
        distance = np.linalg.norm(query[block, None] - exemplars[None], axis=-1)
        weights = 1.0 / np.maximum(distance ** power[block, None], 1e-10)
        hits = distance < EXACT_HIT
        hit_rows = hits.any(axis=1)
        weights[hit_rows] = hits[hit_rows]
        out[block] = (weights @ values) / weights.sum(axis=1, keepdims=True)
    return out
