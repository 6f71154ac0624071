"""Jittered grid (stratified sampling; Cook 1986).

The torus is cut into ``k x k`` square cells, ``k = ceil(sqrt(n))`` (cell side
about one mean spacing ``1/sqrt(n)``); n of the ``k^2`` cells are picked at
random and each gets one point, uniform in the cell. The spectrum is low at low
frequencies (``P_b`` grows like ``b^2`` up to about ``k``) and 1 above, with no
peak: a weaker blue noise than Poisson-disk sampling.

Reference: R. L. Cook, "Stochastic sampling in computer graphics", ACM TOG 5(1), 1986.
"""

from __future__ import annotations

import math

import numpy as np

from ._torus import check_count, wrap


def generate(n: int, rng: np.random.Generator, strength: float = 1.0) -> np.ndarray:
    """(n, 2) float64 points in [0, 1)^2, at most one per cell of a ``ceil(sqrt(n))``-square grid.

    ``strength`` in [0, 1] is the share of its cell a point may lie in (centred):
    1 is the jittered grid, 0 the lattice of cell centres.
    """
    n = check_count(n)
    side = math.isqrt(n - 1) + 1 if n else 1
    cells = rng.choice(side * side, size=n, replace=False)
    corners = np.stack([cells % side, cells // side], axis=1)
    return wrap((corners + 0.5 + strength * (rng.random((n, 2)) - 0.5)) / side)
