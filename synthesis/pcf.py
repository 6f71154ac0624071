"""Pair correlation functions (PCFs) in units of the local point spacing.

A PCF here is sampled at ``m`` radii ``rho`` (default 20, from 0.1 to 2) measured
in units of ``r_max = 2 sqrt(A / (2 sqrt(3) n))``, the largest possible nearest-
neighbour distance of n points in area A (hexagonal packing). Expressing
distances in these units makes the same pattern at different densities have
the same PCF (paper §5, after Zhou et al. 2012).

The estimator is a ratio of observed to expected neighbours: around a point,
neighbours at normalised distance u are soft-counted with a Gaussian
``N(u; rho, sigma)`` (sigma = 0.26), and the count is divided by what a
uniform (Poisson) pattern of the same intensity would give, so a Poisson
pattern has PCF 1 at every radius. Neighbours come from a k-d tree (k = 50
nearest, cut at ``u <= 2 + 3 sigma``). The edge-aware estimator for maps
builds on the same kernel.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from synthesis.errors import PatternshopError

PCF_BINS = 20
RADIUS_RANGE = (0.1, 2.0)  # in units of r_max
KERNEL_SIGMA = 0.26  # in units of r_max
NEIGHBOURS = 50


def r_max(n: float | np.ndarray, area: float = 1.0) -> float | np.ndarray:
    """Largest nearest-neighbour distance of n points in ``area`` (hexagonal packing); works on arrays."""
    return 2.0 * np.sqrt(area / (2.0 * math.sqrt(3.0) * n))


def pcf_radii(bins: int = PCF_BINS, radius_range: tuple[float, float] = RADIUS_RANGE) -> np.ndarray:
    """(bins,) radii rho in units of r_max, evenly spaced over ``radius_range``."""
    return np.linspace(radius_range[0], radius_range[1], bins)


def neighbour_cutoff(radii: np.ndarray, sigma: float = KERNEL_SIGMA) -> float:
    """Largest normalised distance that still matters: the last radius plus 3 sigma."""
    return float(radii[-1] + 3.0 * sigma)


def radial_kernel(distance: np.ndarray, radii: np.ndarray, sigma: float = KERNEL_SIGMA) -> np.ndarray:
    """Gaussian ``N(u; rho, sigma)`` for normalised distances u (...,) -> (..., m)."""
    u = np.asarray(distance)[..., None]
    return np.exp(-0.5 * ((u - radii) / sigma) ** 2) / (sigma * math.sqrt(2.0 * math.pi))


def uniform_expectation(radii: np.ndarray, sigma: float = KERNEL_SIGMA, cutoff: float | None = None) -> np.ndarray:
    """(m,) kernel sum a unit-intensity Poisson pattern gives, per r_max^2, in an unbounded domain.

    ``int_0^cutoff N(u; rho, sigma) 2 pi u du`` by quadrature, the same cutoff as
    the neighbour search so that the ratio is unbiased.
    """
    cutoff = neighbour_cutoff(radii, sigma) if cutoff is None else cutoff
    u = np.linspace(0.0, cutoff, 4097)
    integrand = radial_kernel(u, radii, sigma) * (2.0 * math.pi * u)[:, None]
    return np.trapezoid(integrand, u, axis=0)


def stationary_pcf(
    points: np.ndarray,
    domain: tuple[float, float] = (1.0, 1.0),
    periodic: bool = True,
    radii: np.ndarray | None = None,
    sigma: float = KERNEL_SIGMA,
    neighbours: int = NEIGHBOURS,
) -> np.ndarray:
    """PCF (m,) of a stationary pattern: points (n, 2) in ``[0, w] x [0, h]``.

    ``periodic=True`` treats the domain as a torus (palette exemplars). Otherwise
    the border is handled by minus sampling: only points at least the neighbour
    cutoff away from every border serve as centres (their neighbourhoods are
    complete), while all points count as neighbours.
    """
    radii = pcf_radii() if radii is None else radii
    points = np.asarray(points, np.float64)
    n = len(points)
    w, h = domain
    spacing = r_max(n, w * h)
    cutoff = neighbour_cutoff(radii, sigma)
    if periodic:
        tree = cKDTree(np.mod(points, [w, h]), boxsize=[w, h])
        centres = np.mod(points, [w, h])
    else:
        tree = cKDTree(points)
        margin = cutoff * spacing
        inside = np.all((points >= margin) & (points <= np.array([w, h]) - margin), axis=1)
        centres = points[inside]
        if len(centres) < 10:
            raise PatternshopError(f"only {len(centres)} of {n} points lie far enough from the border to estimate a PCF")
    k = min(neighbours + 1, n)
    distance, _ = tree.query(centres, k=k, distance_upper_bound=cutoff * spacing)
    distance = distance[:, 1:] / spacing  # drop each centre itself
    distance[~np.isfinite(distance)] = np.inf
    counts = radial_kernel(distance, radii, sigma).sum(axis=1).mean(axis=0)
    intensity = (n - 1) / (w * h)
    return counts / (intensity * spacing**2 * uniform_expectation(radii, sigma, cutoff))
