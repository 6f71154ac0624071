"""Geometry of the unit torus [0, 1)^2 shared by the generators.

Lengths are in domain units; for n points the mean spacing is ``1/sqrt(n)`` and
the hexagonal-packing distance is ``r_max = 2 sqrt(1/(2 sqrt(3) n))``
(Lagae and Dutré 2008), the largest possible minimum distance between n points.
"""

from __future__ import annotations

import math
import operator

import numpy as np
from scipy.spatial import cKDTree

from synthesis import pcf
from synthesis.errors import PatternshopError


def check_count(n: int) -> int:
    """``n`` as a non-negative int; PatternshopError for anything else."""
    try:
        count = operator.index(n)
    except TypeError:
        raise PatternshopError(f"point count must be an integer, got {n!r}") from None
    if count < 0:
        raise PatternshopError(f"point count must be >= 0, got {count}")
    return count


def mean_spacing(n: int) -> float:
    """Mean distance ``1/sqrt(n)`` between neighbours of n points on the unit torus."""
    return 1.0 / math.sqrt(max(n, 1))


def r_max(n: int) -> float:
    """Distance ``2 sqrt(1/(2 sqrt(3) n))`` between n points in a hexagonal packing of the torus."""
    return float(pcf.r_max(max(n, 1)))


def wrap(points: np.ndarray) -> np.ndarray:
    """Coordinates (..., 2) wrapped into [0, 1), strictly below 1 (float64)."""
    wrapped = np.mod(np.asarray(points, np.float64), 1.0)
    wrapped[wrapped >= 1.0] = 0.0  # mod of a tiny negative number rounds to 1.0
    return wrapped


def tree(points: np.ndarray) -> cKDTree:
    """k-d tree over (n, 2) points in [0, 1)^2 with periodic (toroidal) distances."""
    return cKDTree(points, boxsize=1.0)


def min_distance(points: np.ndarray) -> float:
    """Smallest toroidal distance between two of the (n, 2) points (inf if n < 2)."""
    if len(points) < 2:
        return math.inf
    distances, _ = tree(points).query(points, k=2)
    return float(distances[:, 1].min())


def gaussian_clusters(centres: np.ndarray, sizes: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """``sizes[i]`` points around each of the (m, 2) ``centres``, isotropic Gaussian offsets of ``std``, wrapped.

    Returns (sizes.sum(), 2) points in [0, 1)^2 in random order (a prefix is a random subset).
    """
    parents = np.repeat(np.asarray(centres, np.float64), sizes, axis=0)
    return rng.permutation(wrap(parents + rng.normal(0.0, std, parents.shape)))
