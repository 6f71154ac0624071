"""Lattices: square or hexagonal, perfect or perturbed.

The torus holds a ``cols x rows`` grid of nodes: square, ``cols = rows =
ceil(sqrt(n))``; hexagonal, an even number of rows (so the half-spacing stagger
of every other row wraps around) ``rows ~ sqrt(2 n / sqrt(3))`` and ``cols =
ceil(n / rows)``, spacings within 5 % of a regular hexagonal packing at
n >= 1,000. n of the nodes get a point (the rest are random vacancies; none
when n fills the grid, e.g. a square n for the square lattice), the whole
lattice is shifted by a uniform random offset, and each point is displaced by
an isotropic Gaussian of ``jitter`` mean spacings ``1/sqrt(n)``. A perfect
lattice (jitter 0) has a spectrum of isolated Bragg peaks, zero elsewhere; the
jitter ``s`` lets through ``1 - exp(-(2 pi s b / sqrt(n))^2)`` of white noise
between them (a perturbed lattice, the most regular of blue noises).

Reference: A. Gabrielli, "Point processes and stochastic displacement fields",
Phys. Rev. E 70, 2004 (perturbed lattices).
"""

from __future__ import annotations

import math

import numpy as np

from ._torus import check_count, mean_spacing, wrap

PERTURBED_JITTER = 0.1  # mean spacings, the "perturbed" preset (hexagonal)


def generate(n: int, rng: np.random.Generator, hexagonal: bool = False, jitter: float = 0.0) -> np.ndarray:
    """(n, 2) float64 points in [0, 1)^2 on a randomly shifted lattice, each jittered by ``jitter`` mean spacings."""
    n = check_count(n)
    if n == 0:
        return np.empty((0, 2))
    if hexagonal:
        rows = max(2, 2 * round(math.sqrt(2.0 * n / math.sqrt(3.0)) / 2.0))
        cols = math.ceil(n / rows)
    else:
        rows = cols = math.isqrt(n - 1) + 1
    nodes = np.sort(rng.choice(rows * cols, size=n, replace=False))
    row, col = np.divmod(nodes, cols)
    stagger = 0.5 * (row % 2) if hexagonal else 0.0
    xy = np.stack([(col + stagger) / cols, row / rows], axis=1) + rng.random(2)
    return wrap(xy + rng.normal(0.0, jitter * mean_spacing(n), xy.shape))


def perturbed(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) hexagonal lattice jittered by :data:`PERTURBED_JITTER` mean spacings (the ``perturbed`` preset)."""
    return generate(n, rng, hexagonal=True, jitter=PERTURBED_JITTER)
