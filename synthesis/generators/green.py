"""Green noise: small clusters of a few points, the clusters themselves spread as blue noise.

``m = round(n/4)`` cluster centres are a blue-noise pattern (:mod:`.blue`); each
cluster gets 2 to 6 points (4 on average, exactly n in all), offset from its
centre by an isotropic Gaussian of standard deviation 0.25 mean spacings
``1/sqrt(n)``. The spectrum is low at the lowest frequencies (0.4-0.8 for
``b < 0.3 sqrt(n)``: the clusters are well spread), has a bump peaking at about 4
near ``b = 0.55 sqrt(n)`` (the clusters' spacing; above 2 for ``b`` in
0.4-0.7 ``sqrt(n)``), and falls to 1 above ``b`` about ``1.3 sqrt(n)`` (the
inverse cluster size).

Reference: D. L. Lau, R. Ulichney, G. R. Arce, "Blue- and green-noise halftoning
models", IEEE Signal Processing Magazine 20(4), 2003.
"""

from __future__ import annotations

import numpy as np

from . import blue
from ._torus import check_count, gaussian_clusters, mean_spacing

POINTS_PER_CLUSTER = 4  # on average
MIN_CLUSTER = 2  # points; the largest cluster holds 2 POINTS_PER_CLUSTER - MIN_CLUSTER (6 by default)
CLUSTER_STD = 0.25  # mean spacings


def generate(n: int, rng: np.random.Generator, points_per_cluster: int = POINTS_PER_CLUSTER,
             cluster_std: float = CLUSTER_STD) -> np.ndarray:
    """(n, 2) float64 points in [0, 1)^2 in clusters of 2 to ``2 points_per_cluster - 2`` (2-6 by default;
    fewer only if n < 2), offsets of ``cluster_std`` mean spacings, the clusters spread as blue noise."""
    n = check_count(n)
    clusters = max(1, round(n / points_per_cluster))
    centres = blue.generate(clusters, rng)
    sizes = _cluster_sizes(n, clusters, max(MIN_CLUSTER + 1, 2 * points_per_cluster - MIN_CLUSTER), rng)
    return gaussian_clusters(centres, sizes, cluster_std * mean_spacing(n), rng)


def _cluster_sizes(n: int, clusters: int, largest: int, rng: np.random.Generator) -> np.ndarray:
    """(clusters,) random sizes in [MIN_CLUSTER, largest] summing to n.

    Every cluster gets ``MIN_CLUSTER`` points (fewer if n is too small); the
    rest fill randomly chosen free slots, at most ``largest - MIN_CLUSTER``
    per cluster. Needs ``n <= largest * clusters``.
    """
    base = min(MIN_CLUSTER, n // clusters)
    spare = largest - MIN_CLUSTER
    slots = rng.choice(spare * clusters, size=n - base * clusters, replace=False)
    return base + np.bincount(slots // spare, minlength=clusters)
