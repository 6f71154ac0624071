"""White noise: a binomial (fixed-count Poisson) point process.

Every point is independent and uniform on the torus; the power spectrum is flat,
``P_b = 1`` at every frequency. No parameters.
"""

from __future__ import annotations

import numpy as np

from ._torus import check_count


def generate(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) float64 points, independent and uniform in [0, 1)^2."""
    return rng.random((check_count(n), 2))
