"""Parametric families of the palette corpus: known point processes swept over their parameters.

The random GMM spectra of :mod:`data_gen.corpus` rarely produce the patterns
users meet at the ends of the gamut: nothing there is more regular than a weak
blue noise, and few exemplars are strongly clustered. This module adds, from
the perfect lattice to large clusters (palette v2, issue 13):

====================  =====================================================  =========
family                parameter swept (generator in :mod:`synthesis.generators`)  values
====================  =====================================================  =========
square lattice        jitter, mean spacings (``lattice``)                    0 - 0.4
hexagonal lattice     jitter, mean spacings (``lattice``, hexagonal)         0 - 0.4
Lloyd-relaxed         iterations (``lloyd``)                                  1 - 80
Poisson-disk          radius, r_max (``blue``)                                0.2 - 0.76
jittered grid         share of the cell (``jitter``)                          0.25 - 1
step                  (``step``)                                              -
Poisson               (``white``)                                             -
green noise           points per cluster x spread (``green``)                 3 - 6 x 0.15 - 0.4
Thomas clusters       points per cluster x spread (``red``)                   4 - 32 x 0.15 - 1 spacings
Matérn clusters       points per cluster x disk radius (``matern``)           4 - 32 x 0.3 - 2 spacings
====================  =====================================================  =========

Every setting is realised with a few seeds (exemplar i uses
``default_rng([seed, FAMILY_STREAM, i])``) at the corpus point count on the
torus; its PCF and perceptual features are measured as for the GMM corpus and
cached in chunks (resumable, independent of chunking and workers). The
exemplar's "target" spectrum is its own measured radial spectrum.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FAMILY_STREAM = 13  # keeps the families' random streams apart from the GMM exemplars'
FORMAT = 1  # chunk contents; bump to invalidate cached families


@dataclass(frozen=True)
class FamilyExemplar:
    """One corpus exemplar to generate: ``generator(n, rng, **parameters)`` with seed number ``replica``."""

    family: str
    generator: str
    parameters: tuple[tuple[str, object], ...]
    replica: int

    def label(self) -> str:
        """Human-readable name, e.g. ``thomas(points_per_cluster=8, cluster_std=0.3)#1``."""
        arguments = ", ".join(f"{key}={value}" for key, value in self.parameters)
        return f"{self.family}({arguments})#{self.replica}"


def _sweep(family: str, generator: str, replicas: int, **grids: list) -> list[FamilyExemplar]:
    """Every combination of the parameter grids, ``replicas`` seeds each."""
    keys = list(grids)
    return [FamilyExemplar(family, generator, tuple(zip(keys, values)), replica)
            for values in itertools.product(*grids.values()) for replica in range(replicas)]


def family_exemplars() -> list[FamilyExemplar]:
    """The parametric part of the corpus (see the module docstring), in a fixed order."""
    jitters = [0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4]
    return [
        *_sweep("square lattice", "lattice", 2, hexagonal=[False], jitter=jitters),
        *_sweep("hexagonal lattice", "lattice", 2, hexagonal=[True], jitter=jitters),
        *_sweep("lloyd", "lloyd", 2, iterations=[1, 2, 3, 5, 8, 12, 20, 30, 50, 80]),
        *_sweep("poisson-disk", "blue", 2, relative_radius=[0.2, 0.3, 0.4, 0.5, 0.6, 0.65, 0.7, 0.74, 0.76]),
        *_sweep("jittered grid", "jitter", 2, strength=[0.25, 0.5, 0.75, 0.9, 1.0]),
        *_sweep("step", "step", 4),
        *_sweep("poisson", "white", 8),
        *_sweep("green", "green", 2, points_per_cluster=[3, 4, 6], cluster_std=[0.15, 0.25, 0.4]),
        *_sweep("thomas", "red", 3, points_per_cluster=[4, 8, 16, 32], cluster_std=[0.15, 0.3, 0.6, 1.0]),
        *_sweep("matern", "matern", 3, points_per_cluster=[4, 8, 16, 32], radius=[0.3, 0.6, 1.2, 2.0]),
    ]


def realise(exemplar: FamilyExemplar, points: int, seed: int, index: int) -> np.ndarray:
    """(points, 2) toroidal realisation of exemplar number ``index`` of the list."""
    from synthesis.generators import GENERATORS

    rng = np.random.default_rng([seed, FAMILY_STREAM, index])
    return GENERATORS[exemplar.generator](points, rng, **dict(exemplar.parameters))


def _make_chunk(points: int, seed: int, extractor: tuple, indexed: list[tuple[int, FamilyExemplar]]) -> dict[str, np.ndarray]:
    """Realise, measure and featurise the exemplars ``indexed`` (runs in a worker process)."""
    import torch

    from synthesis.features import FeatureExtractor
    from synthesis.pcf import stationary_pcf
    from synthesis.spectrum import RadialSpectrum

    torch.set_num_threads(1)
    features = FeatureExtractor(**{k: v for k, v in extractor if k != "version"})
    spectrum = RadialSpectrum(points)
    out: dict[str, list] = {"index": [], "points": [], "target": [], "pcf": [], "features": []}
    for index, exemplar in indexed:
        xy = realise(exemplar, points, seed, index)
        out["index"].append(index)
        out["points"].append(xy)
        out["target"].append(spectrum(xy))
        out["pcf"].append(stationary_pcf(xy, periodic=True))
        out["features"].append(features(xy, (1.0, 1.0), periodic=True))
    return {name: np.asarray(values) for name, values in out.items()}


def build_families(points: int, seed: int, extractor: tuple, cache_dir: str | Path, workers: int = 1,
                   chunk: int = 25, stride: int = 1) -> dict[str, np.ndarray]:
    """The family exemplars (every ``stride``-th of :func:`family_exemplars`): arrays ``index``,
    ``points (F, P, 2)``, ``target (F, 64)``, ``pcf (F, m)``, ``features (F, D)``, ``family (F,)`` and
    ``label (F,)`` strings, and ``computed_now``."""
    from data_gen.corpus import cached_chunks

    exemplars = family_exemplars()[::stride]
    description = {"format": FORMAT, "points": points, "seed": seed, "extractor": extractor,
                   "exemplars": [exemplar.label() for exemplar in exemplars]}
    key = hashlib.sha256(json.dumps(description, sort_keys=True, default=str).encode()).hexdigest()[:16]
    indexed = list(enumerate(exemplars))
    chunks = [indexed[start : start + chunk] for start in range(0, len(indexed), chunk)]
    result = cached_chunks(Path(cache_dir) / f"families-{key}", description,
                           functools.partial(_make_chunk, points, seed, extractor), chunks, workers, "families")
    result["family"] = np.array([exemplar.family for exemplar in exemplars])
    result["label"] = np.array([exemplar.label() for exemplar in exemplars])
    return result
