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


def compressed(dissimilarity: np.ndarray, fraction: float | None) -> np.ndarray:
    """(N, N) ``log(1 + D / s)`` with ``s = fraction * median(D)`` (off-diagonal); ``None`` returns D unchanged.

    The L1 distances between Gram features span three orders of magnitude: a
    strongly clustered pattern is 50 times farther from white noise than a
    lattice is from a Poisson-disk pattern. Embedded as they are, a few
    extreme clusters set the scale and every non-clustered pattern lands
    within a few ab units of the centre. The logarithm keeps the order of the
    distances (so neighbourhoods, and trustworthiness, are unchanged) and
    measures large ones by their ratio rather than their difference.
    """
    if fraction is None:
        return dissimilarity
    scale = fraction * float(np.median(dissimilarity[np.triu_indices(len(dissimilarity), 1)]))
    return np.log1p(dissimilarity / scale)


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


def hue_warp(angles: np.ndarray, strength: float) -> np.ndarray:
    """Monotone map of angles (N,) in degrees that spreads them towards a uniform distribution.

    ``(1 - strength) * angle + strength * F(angle)``, where F is the exemplars'
    empirical angular distribution function (linearly interpolated, scaled to
    360 degrees) counted from the middle of the widest empty sector; strength 0
    is the identity, 1 spreads the exemplars evenly over the hues. Order around
    the centre is kept, so neighbours stay neighbours; distances change.
    """
    if strength == 0.0 or len(angles) < 2:
        return np.asarray(angles, np.float64) % 360.0
    ordered = np.sort(np.asarray(angles, np.float64) % 360.0)
    gaps = np.diff(np.append(ordered, ordered[0] + 360.0))
    widest = int(np.argmax(gaps))
    origin = ordered[widest] + gaps[widest] / 2.0  # the cut of the distribution function
    relative = (np.asarray(angles, np.float64) - origin) % 360.0
    knots = np.sort(relative)
    rank = (np.arange(len(knots)) + 0.5) / len(knots) * 360.0
    spread = np.interp(relative, np.concatenate([[0.0], knots, [360.0]]), np.concatenate([[0.0], rank, [360.0]]))
    return (origin + (1.0 - strength) * relative + strength * spread) % 360.0


def pin_hues(angles: np.ndarray, anchor_angles: np.ndarray, wanted: np.ndarray) -> np.ndarray | None:
    """Piecewise-linear monotone map of angles (N,) in degrees taking ``anchor_angles`` (K,) exactly to ``wanted`` (K,).

    Each sector between two anchors (in cyclic order) is stretched or squeezed
    linearly onto the sector between their wanted hues, so order around the
    centre is kept. Returns None when the anchors' cyclic order differs from
    their wanted hues' (no monotone map exists).
    """
    order = np.argsort(np.asarray(anchor_angles) % 360.0)
    start, target = np.asarray(anchor_angles, np.float64)[order] % 360.0, np.asarray(wanted, np.float64)[order] % 360.0
    source_gaps = (np.roll(start, -1) - start) % 360.0
    target_gaps = (np.roll(target, -1) - target) % 360.0
    if len(start) < 2 or not np.isclose(target_gaps.sum(), 360.0) or np.any(source_gaps <= 0):
        return None
    relative = (np.asarray(angles, np.float64)[:, None] - start[None]) % 360.0  # (N, K) forward offset from each anchor
    sector = np.argmin(np.where(relative < source_gaps[None], relative, np.inf), axis=1)
    offset = relative[np.arange(len(relative)), sector]
    return (target[sector] + offset / source_gaps[sector] * target_gaps[sector]) % 360.0


def orient(
    layout: np.ndarray, anchors: dict[str, np.ndarray], hues: dict[str, float], centre: str | None = "white",
    warp: float = 0.0, blue_window: float = 40.0, fill_quantile: float = 0.995, pin: bool = False,
) -> tuple[np.ndarray, dict]:
    """Place a layout in the ab square: ``centre`` at a = b = 0, the other anchors on their hues.

    The layout is moved so that ``anchors[centre]`` (white noise: no correlation,
    hence no chroma) sits at the origin (the layout's mean without a centre),
    optionally warped in angle around it (:func:`hue_warp` with ``warp``; radii
    are kept), then rotated in 1 degree steps, with and without a reflection:
    among the orientations that put ``anchors["blue"]`` within ``blue_window``
    degrees of its hue, the one with the smallest summed hue error of all
    anchors wins (falling back to all candidates if none qualifies). With
    ``pin``, a piecewise-linear angular map (:func:`pin_hues`) then puts every
    anchor exactly on its hue (when their cyclic order allows it). One
    scale for both axes (no per-axis stretching) brings the ``fill_quantile``
    of the exemplars' largest |a| or |b| to 127; the few beyond are clipped
    onto the square's border.

    Args:
        layout: (N, 2) MDS coordinates.
        anchors: name -> (2,) MDS coordinates of a reference pattern (needs "blue").
        hues: name -> wanted hue angle in degrees (atan2(b, a)); the centre's is ignored.

    Returns:
        (N, 2) latent z in [0, 1], and a record of the transform.
    """
    origin = np.asarray(anchors[centre] if centre in anchors else layout.mean(axis=0), np.float64)
    names = [name for name in hues if name != centre]
    blue = names.index("blue")
    wanted = np.array([hues[name] for name in names])
    best = None
    for reflect in (False, True):
        flip = np.array([1.0, -1.0 if reflect else 1.0])
        relative = (np.concatenate([layout, np.stack([anchors[name] for name in names])]) - origin) * flip
        radius = np.linalg.norm(relative, axis=1)
        angle = np.degrees(np.arctan2(relative[:, 1], relative[:, 0]))
        warped = angle
        if warp:  # anchors are exemplars or near them: they follow their nearest exemplar's warp
            warped = np.concatenate([hue_warp(angle[: len(layout)], warp), [0.0] * len(names)])
            nearest = np.argmin(np.linalg.norm(layout[None] - np.stack([anchors[name] for name in names])[:, None], axis=-1), axis=1)
            warped[len(layout):] = angle[len(layout):] + ((warped[nearest] - angle[nearest] + 180.0) % 360.0 - 180.0)
        for degrees in range(360):
            error = np.abs((warped[len(layout):] + degrees - wanted + 180.0) % 360.0 - 180.0)
            key = (not error[blue] <= blue_window, float(error.sum()))
            if best is None or key < best[0]:
                best = (key, reflect, degrees, radius, warped)
    _, reflected, degrees, radius, warped = best
    final = warped[: len(layout)] + degrees
    pinned = pin_hues(final, warped[len(layout):] + degrees, wanted) if pin else None
    turned = np.radians(final if pinned is None else pinned)
    ab = radius[: len(layout), None] * np.stack([np.cos(turned), np.sin(turned)], axis=1)
    scale = 127.0 / np.quantile(np.abs(ab).max(axis=1), fill_quantile)
    z = (np.clip(ab * scale, -128.0, 127.0) + 128.0) / 255.0
    record = {"origin": origin.tolist(), "centre": centre if centre in anchors else None, "reflected": bool(reflected),
              "rotation_degrees": degrees, "warp": warp, "hues_pinned": pinned is not None, "scale_ab_per_unit": float(scale),
              "clipped": int(np.sum(np.abs(ab * scale).max(axis=1) > 127.0))}
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
