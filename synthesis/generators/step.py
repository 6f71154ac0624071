"""Step blue noise: radial power spectrum 0 below a cutoff frequency and 1 above.

The points are fitted to the target spectrum ``P_b = 0`` for ``1 <= b < c`` and
``P_b = 1`` for ``c <= b <= 63`` by gradient descent on their positions
(:func:`synthesis.spectrum.fit_spectrum`: Adam, 500 iterations, learning rate
0.064 mean spacings ``1/sqrt(n)``, from white noise). The cutoff scales with
the density, ``c = 16 sqrt(n/1024)`` cycles per domain side, i.e. 0.5 ``sqrt(n)``:
with the step at 0.75 ``sqrt(n)`` the pattern is perceptually indistinguishable
from Poisson-disk blue noise (their Gram-feature distance is at the level of
two realisations of one), while at 0.5 ``sqrt(n)`` it is a distinct, softer
blue. The result has ``P_b`` about 0.1 below the cutoff and about 1.05 above.

The spectrum machinery resolves ``b <= 63`` only, so the cutoff would leave too
few controlled bins above it (and pass b = 63 at n ~ 7,000): n is limited to
``MAX_POINTS = 4096`` (cutoff 32). Fitting costs about 1 s at n = 1024.

Reference: D. Heck, T. Schlömer, O. Deussen, "Blue noise sampling with
controlled aliasing", ACM TOG 32(3), 2013.
"""

from __future__ import annotations

import math

import numpy as np

from synthesis.errors import PatternshopError
from synthesis.spectrum import SPECTRUM_BINS, fit_spectrum

from ._torus import check_count, mean_spacing, wrap

MAX_POINTS = 4096
CUTOFF_AT_1024 = 16.0  # radial bin of the step at n = 1024
ITERATIONS = 500
LEARNING_RATE = 0.064  # mean spacings


def cutoff(n: int) -> float:
    """Step frequency ``16 sqrt(n/1024)`` in cycles per domain side."""
    return CUTOFF_AT_1024 * math.sqrt(n / 1024)


def target_spectrum(n: int) -> np.ndarray:
    """(64,) target radial spectrum: 0 below :func:`cutoff` (and at b = 0), 1 from it on."""
    bins = np.arange(SPECTRUM_BINS)
    return (bins >= cutoff(n)).astype(np.float64)


def generate(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) float64 points in [0, 1)^2 with a step spectrum; n <= 4096."""
    n = check_count(n)
    if n > MAX_POINTS:
        raise PatternshopError(
            f"step noise is limited to {MAX_POINTS} points (asked for {n}): its cutoff "
            f"{cutoff(n):.0f} leaves too few of the {SPECTRUM_BINS} spectrum bins above it"
        )
    if n == 0:
        return np.empty((0, 2))
    fit = fit_spectrum(target_spectrum(n), n, rng, ITERATIONS, LEARNING_RATE * mean_spacing(n))
    return wrap(fit.points)  # np.mod in the fit can round -1e-18 up to 1.0
