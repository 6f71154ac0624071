"""Matérn cluster process: small, hard-edged clumps.

``m = round(n / points_per_cluster)`` parents are uniform on the torus; each of
the n points picks a parent uniformly (multinomial cluster sizes, exactly n in
all) and lies uniformly in the disk of ``radius`` mean spacings ``1/sqrt(n)``
around it. The ``matern`` preset uses 6 points in disks of 0.5 mean spacings:
tight clumps of a few points, the clumps placed at random (unlike green noise,
whose clusters are spread as blue noise, and the larger, softer Thomas
clusters of ``red``).

Reference: B. Matérn, "Spatial variation", Lecture Notes in Statistics 36,
Springer 1986; J. Illian et al., "Statistical analysis and modelling of
spatial point patterns", Wiley 2008, Sec. 6.3.
"""

from __future__ import annotations

import numpy as np

from ._torus import check_count, mean_spacing, wrap

POINTS_PER_CLUSTER = 6  # on average
RADIUS = 0.5  # mean spacings


def generate(n: int, rng: np.random.Generator, points_per_cluster: float = POINTS_PER_CLUSTER,
             radius: float = RADIUS) -> np.ndarray:
    """(n, 2) float64 points in [0, 1)^2, uniform in disks of ``radius`` mean spacings around random parents."""
    n = check_count(n)
    parents = max(1, round(n / points_per_cluster))
    owner = np.repeat(np.arange(parents), rng.multinomial(n, np.full(parents, 1.0 / parents)))
    centres = rng.random((parents, 2))[owner]
    distance = radius * mean_spacing(n) * np.sqrt(rng.random(n))
    angle = 2.0 * np.pi * rng.random(n)
    return rng.permutation(wrap(centres + np.stack([distance * np.cos(angle), distance * np.sin(angle)], axis=1)))
