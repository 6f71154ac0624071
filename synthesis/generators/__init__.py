"""Reference point-pattern generators on the unit torus, one module per correlation.

Every generator is ``generate(n, rng) -> (n, 2)`` float64 points in [0, 1)^2,
exactly n of them, the domain being periodic (toroidal); the same ``rng`` state
gives the same points. Parameters scale with the mean spacing ``1/sqrt(n)``, so a
pattern looks the same at any n. The correlations, by their radial power
spectrum ``P_b`` (1 for white noise; see :mod:`synthesis.spectrum`):

* ``white``: Poisson (binomial) process; independent uniform points, flat spectrum.
* ``blue``: Poisson-disk sampling; points well separated, no low frequencies,
  a peak at the mean spacing (Lagae and Dutré 2008).
* ``green``: small clusters of 2-6 points, the clusters spread as blue noise;
  low power at the lowest frequencies, a bump at mid frequencies
  (Lau, Ulichney and Arce 2003).
* ``red``: Thomas cluster process; large clusters, energy at low
  frequencies (red/pink noise).
* ``step``: step blue noise; ``P_b`` about 0 below a cutoff and 1 above
  (Heck, Schlömer and Deussen 2013). At most 4096 points.
* ``jitter``: jittered grid; one point per grid cell, a weak blue noise (Cook 1986).
* ``lattice``: perfect square lattice (randomly shifted); Bragg peaks only.
* ``perturbed``: hexagonal lattice, each point jittered by 0.1 mean spacings; the most regular blue noise.
* ``lloyd``: Lloyd-relaxed points (30 iterations of a centroidal Voronoi tessellation); a strong blue noise.
* ``matern``: Matérn clusters; tight clumps of about 6 points at random places.

Most modules also take parameters (radius, jitter, cluster size, ...) as keyword
arguments of their ``generate``; the palette corpus (:mod:`data_gen.families`)
sweeps them.

Use :func:`generate` with a name and a seed, or :data:`GENERATORS` with a
``numpy.random.Generator``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from synthesis.errors import PatternshopError

from . import blue, green, jitter, lattice, lloyd, matern, red, step, white

Generator = Callable[[int, np.random.Generator], np.ndarray]

GENERATORS: dict[str, Generator] = {
    "white": white.generate,
    "blue": blue.generate,
    "green": green.generate,
    "red": red.generate,
    "step": step.generate,
    "jitter": jitter.generate,
    "lattice": lattice.generate,
    "perturbed": lattice.perturbed,
    "lloyd": lloyd.generate,
    "matern": matern.generate,
}


def generate(name: str, n: int, seed: int = 0) -> np.ndarray:
    """(n, 2) float64 points in [0, 1)^2 from the generator ``name``, seeded with ``seed``."""
    try:
        generator = GENERATORS[name]
    except (KeyError, TypeError):
        raise PatternshopError(f"unknown pattern generator {name!r}; choose one of: {', '.join(GENERATORS)}") from None
    return generator(n, np.random.default_rng(seed))


__all__ = ["GENERATORS", "Generator", "generate"]
