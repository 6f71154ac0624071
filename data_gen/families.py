"""Parametric families of the palette corpus: known point processes swept over their parameters.

The random GMM spectra of :mod:`data_gen.corpus` rarely produce the patterns
users meet at the ends of the gamut: nothing there is more regular than a weak
blue noise, and few exemplars are strongly clustered. This module adds, from
the perfect lattice to large clusters:

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
Thomas clusters       points per cluster x spread (``red``)                   3 - 32 x 0.15 - 1 spacings
Matérn clusters       points per cluster x disk radius (``matern``)           3 - 32 x 0.3 - 2 spacings
====================  =====================================================  =========

Every setting is one exemplar standing for its process, not for one draw of it:
its PCF, radial spectrum and perceptual features are the means over
:data:`REALISATIONS` independent toroidal realisations at the corpus point count
(realisation r of exemplar i uses ``default_rng([seed, FAMILY_STREAM, i, r])``);
its stored points are the first realisation. A clustered pattern of 1,024 points
has only 30-250 clusters, so one realisation's Gram features scatter as far as
the features of neighbouring settings (in a layout built from single draws,
two seeds of one Matérn setting landed 60 ab units apart, and a Thomas pattern
decoded anywhere between them). Results are cached in chunks
(resumable, independent of chunking and workers). The exemplar's "target"
spectrum is its measured mean radial spectrum.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from data_gen.executor import Executor
from data_gen.storage import as_path

FAMILY_STREAM = 13  # keeps the families' random streams apart from the GMM exemplars'
FORMAT = 2  # chunk contents; bump to invalidate cached families (2: means over REALISATIONS)
REALISATIONS = 4  # independent draws averaged into one exemplar


@dataclass(frozen=True)
class FamilyExemplar:
    """One corpus exemplar: the process ``generator(n, rng, **parameters)``; ``replica`` numbers repeated settings."""

    family: str
    generator: str
    parameters: tuple[tuple[str, object], ...]
    replica: int

    def label(self) -> str:
        """Human-readable name, e.g. ``thomas(points_per_cluster=8, cluster_std=0.3)#1``."""
        arguments = ", ".join(f"{key}={value}" for key, value in self.parameters)
        return f"{self.family}({arguments})#{self.replica}"


def _sweep(family: str, generator: str, replicas: int = 1, **grids: list) -> list[FamilyExemplar]:
    """Every combination of the parameter grids, ``replicas`` exemplars each."""
    keys = list(grids)
    return [FamilyExemplar(family, generator, tuple(zip(keys, values)), replica)
            for values in itertools.product(*grids.values()) for replica in range(replicas)]


def family_exemplars() -> list[FamilyExemplar]:
    """The parametric part of the corpus (see the module docstring), in a fixed order."""
    jitters = [0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4]
    sizes = [3, 4, 6, 8, 12, 16, 24, 32]
    return [
        *_sweep("square lattice", "lattice", hexagonal=[False], jitter=jitters),
        *_sweep("hexagonal lattice", "lattice", hexagonal=[True], jitter=jitters),
        *_sweep("lloyd", "lloyd", iterations=[1, 2, 3, 5, 8, 12, 20, 30, 50, 80]),
        *_sweep("poisson-disk", "blue", relative_radius=[0.2, 0.3, 0.4, 0.5, 0.55, 0.6, 0.65, 0.7, 0.74, 0.76]),
        *_sweep("jittered grid", "jitter", strength=[0.25, 0.5, 0.75, 0.9, 1.0]),
        *_sweep("step", "step"),
        *_sweep("poisson", "white", 2),
        *_sweep("green", "green", points_per_cluster=[3, 4, 6], cluster_std=[0.15, 0.25, 0.4]),
        *_sweep("thomas", "red", points_per_cluster=sizes, cluster_std=[0.15, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0]),
        *_sweep("matern", "matern", points_per_cluster=sizes, radius=[0.3, 0.45, 0.6, 0.9, 1.2, 1.6, 2.0]),
    ]


def realise(exemplar: FamilyExemplar, points: int, seed: int, index: int, realisation: int = 0) -> np.ndarray:
    """(points, 2) toroidal realisation number ``realisation`` of exemplar number ``index`` of the list."""
    from synthesis.generators import GENERATORS

    rng = np.random.default_rng([seed, FAMILY_STREAM, index, realisation])
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
        draws = [realise(exemplar, points, seed, index, r) for r in range(REALISATIONS)]
        out["index"].append(index)
        out["points"].append(draws[0])
        out["target"].append(np.mean([spectrum(xy) for xy in draws], axis=0))
        out["pcf"].append(np.mean([stationary_pcf(xy, periodic=True) for xy in draws], axis=0))
        out["features"].append(np.mean([features(xy, (1.0, 1.0), periodic=True) for xy in draws], axis=0))
    return {name: np.asarray(values) for name, values in out.items()}


def build_families(points: int, seed: int, extractor: tuple, cache_dir: str | Path, executor: Executor = Executor(workers=1),
                   chunk: int = 25, stride: int = 1) -> dict[str, np.ndarray]:
    """The family exemplars (every ``stride``-th of :func:`family_exemplars`, computed on ``executor``): arrays ``index``,
    ``points (F, P, 2)``, ``target (F, 64)``, ``pcf (F, m)``, ``features (F, D)``, ``family (F,)`` and
    ``label (F,)`` strings, and ``computed_now``."""
    from data_gen.corpus import cached_chunks

    exemplars = family_exemplars()[::stride]
    description = {"format": FORMAT, "realisations": REALISATIONS, "points": points, "seed": seed, "extractor": extractor,
                   "exemplars": [exemplar.label() for exemplar in exemplars]}
    key = hashlib.sha256(json.dumps(description, sort_keys=True, default=str).encode()).hexdigest()[:16]
    indexed = list(enumerate(exemplars))
    chunks = [indexed[start : start + chunk] for start in range(0, len(indexed), chunk)]
    result = cached_chunks(as_path(cache_dir) / f"families-{key}", description,
                           functools.partial(_make_chunk, points, seed, extractor), chunks, executor, "families")
    result["family"] = np.array([exemplar.family for exemplar in exemplars])
    result["label"] = np.array([exemplar.label() for exemplar in exemplars])
    return result
