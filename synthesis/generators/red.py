"""Red (pink) noise: a Thomas cluster process, its power concentrated at low frequencies.

``m = round(n/16)`` parents are uniform on the torus (white noise); each of the
n points picks a parent uniformly (so clusters hold 16 points on average,
multinomially distributed, exactly n in all) and is offset from it by an
isotropic Gaussian of standard deviation 0.6 mean spacings ``1/sqrt(n)``. The
spectrum is about ``1 + 16 exp(-2 (pi sigma k)^2)``: 15-20 at the lowest
frequencies, falling to 1 by ``b`` about ``0.6 sqrt(n)``: tight, visible clumps.

Reference: M. Thomas, "A generalization of Poisson's binomial limit for use in
ecology", Biometrika 36(1/2), 1949; J. Illian et al., "Statistical analysis and
modelling of spatial point patterns", Wiley 2008, Sec. 6.3.
"""

from __future__ import annotations

import numpy as np

from ._torus import check_count, gaussian_clusters, mean_spacing

POINTS_PER_CLUSTER = 16  # on average
CLUSTER_STD = 0.6  # mean spacings


def generate(n: int, rng: np.random.Generator, points_per_cluster: float = POINTS_PER_CLUSTER,
             cluster_std: float = CLUSTER_STD) -> np.ndarray:
    """(n, 2) float64 points in [0, 1)^2, Gaussian clusters (``cluster_std`` mean spacings) around
    ``round(n / points_per_cluster)`` random parents."""
    n = check_count(n)
    parents = max(1, round(n / points_per_cluster))
    sizes = rng.multinomial(n, np.full(parents, 1.0 / parents))
    return gaussian_clusters(rng.random((parents, 2)), sizes, cluster_std * mean_spacing(n), rng)
