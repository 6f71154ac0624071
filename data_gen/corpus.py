"""The palette corpus: random radial power spectra realised as point sets.

Each exemplar i (SPEC §2.1, supplemental §1.1):

1. a target radial power spectrum ``p_b = sum_k w_k exp(-(b - mu_k)^2 / (2 sigma_k^2)) + gamma``
   over b = 0..63 with ``p_0 = 0``, 1 or 2 modes, gamma in {0, 1},
   mu in [0, 68], sigma in [2, 12], w in [1, 3];
2. a point set on the unit torus realising it, by gradient descent on the
   points through a differentiable (NUFFT) spectrum;
3. its PCF (stationary, toroidal estimator of :mod:`synthesis.pcf`) and its
   perceptual features (:mod:`synthesis.features`).

Exemplar i uses the random stream ``default_rng([seed, i])`` so results do not
depend on chunking or on the number of workers. Chunks are cached as ``.npz``
files, so an interrupted build resumes where it stopped.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
from tqdm import tqdm

from data_gen.executor import Executor, Lost
from data_gen.storage import as_path, write_atomic, write_text_atomic
from synthesis.errors import PatternshopError


@dataclass(frozen=True)
class SpectrumRanges:
    """Parameter ranges of the random GMM spectra (supplemental §1.1)."""

    bins: int = 64
    modes: tuple[int, int] = (1, 2)
    gamma: tuple[int, int] = (0, 1)
    mu: tuple[float, float] = (0.0, 68.0)
    sigma: tuple[float, float] = (2.0, 12.0)
    weight: tuple[float, float] = (1.0, 3.0)


@dataclass(frozen=True)
class CorpusConfig:
    """What determines a corpus (and its cache key)."""

    exemplars: int = 1000
    points: int = 1024
    seed: int = 0
    spectrum: SpectrumRanges = SpectrumRanges()
    fit_iterations: int = 200
    fit_learning_rate: float = 2e-3
    chunk: int = 25
    format: int = 2  # chunk contents; bump to invalidate old caches
    extractor: tuple[tuple[str, object], ...] = (("name", "random-cnn"), ("seed", 0), ("weights", None), ("version", 1))

    def key(self) -> str:
        """Short hash identifying the corpus contents."""
        text = json.dumps(asdict(self), sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def random_spectrum(rng: np.random.Generator, ranges: SpectrumRanges) -> np.ndarray:
    """(bins,) random radial power spectrum as in supplemental eq. 1; entry 0 is 0."""
    b = np.arange(ranges.bins, dtype=np.float64)
    spectrum = np.zeros(ranges.bins)
    for _ in range(rng.integers(ranges.modes[0], ranges.modes[1] + 1)):
        mu, sigma, weight = rng.uniform(*ranges.mu), rng.uniform(*ranges.sigma), rng.uniform(*ranges.weight)
        spectrum += weight * np.exp(-((b - mu) ** 2) / (2.0 * sigma**2))
    spectrum += rng.integers(ranges.gamma[0], ranges.gamma[1] + 1)
    spectrum[0] = 0.0
    return spectrum


def _make_chunk(config: CorpusConfig, indices: list[int]) -> dict[str, np.ndarray]:
    """Realise, measure and featurise exemplars ``indices`` (runs in a worker process)."""
    import torch

    from synthesis.features import FeatureExtractor
    from synthesis.pcf import stationary_pcf
    from synthesis.spectrum import RadialSpectrum, fit_spectrum

    torch.set_num_threads(1)
    extractor = FeatureExtractor(**{k: v for k, v in config.extractor if k != "version"})
    spectrum = RadialSpectrum(config.points, config.spectrum.bins)
    out: dict[str, list] = {"index": [], "target": [], "points": [], "realised": [], "fit_rms": [], "pcf": [],
                            "features": [], "seconds": []}
    for index in indices:
        start = time.perf_counter()
        rng = np.random.default_rng([config.seed, index])
        target = random_spectrum(rng, config.spectrum)
        fit = fit_spectrum(target, config.points, rng, config.fit_iterations, config.fit_learning_rate, spectrum)
        out["index"].append(index)
        out["target"].append(target)
        out["points"].append(fit.points)
        out["realised"].append(fit.spectrum)
        out["fit_rms"].append(fit.rms_error)
        out["pcf"].append(stationary_pcf(fit.points, periodic=True))
        out["features"].append(extractor(fit.points, (1.0, 1.0), periodic=True))
        out["seconds"].append(time.perf_counter() - start)
    return {name: np.asarray(values) for name, values in out.items()}


def build_corpus(config: CorpusConfig, cache_dir: str | os.PathLike, executor: Executor = Executor()) -> dict[str, np.ndarray]:
    """All exemplars, from the chunk cache where present; missing chunks are computed in parallel on ``executor``.

    Returns arrays ``index (N,)``, ``target (N, B)``, ``points (N, P, 2)``,
    ``realised (N, B)``, ``fit_rms (N,)``, ``pcf (N, m)``, ``features (N, D)``,
    ``seconds (N,)`` (worker time per exemplar, whenever it was computed) and
    ``computed_now`` (how many exemplars this call computed rather than read).
    """
    folder = as_path(cache_dir) / f"corpus-{config.key()}"
    chunks = [list(range(start, min(start + config.chunk, config.exemplars))) for start in range(0, config.exemplars, config.chunk)]
    return cached_chunks(folder, asdict(config), functools.partial(_make_chunk, config), chunks, executor, "corpus")


def _indexed(make_chunk: Callable[[list], dict[str, np.ndarray]], numbered: tuple[int, list]) -> tuple[int, dict[str, np.ndarray]]:
    """(chunk number, ``make_chunk(items)``) of a numbered chunk (runs on a worker)."""
    number, items = numbered
    return number, make_chunk(items)


def cached_chunks(folder: str | os.PathLike, description: dict, make_chunk: Callable[[list], dict[str, np.ndarray]], chunks: list[list],
                  executor: Executor, label: str) -> dict[str, np.ndarray]:
    """Concatenated results of ``make_chunk(items)`` over ``chunks``, each chunk cached as ``folder/chunk-NNNN.npz``.

    Missing chunks are computed on ``executor`` (:mod:`data_gen.executor`; locally in spawned processes even for
    one worker; ``make_chunk`` must be picklable) and written atomically by this process as they come back, so an
    interrupted run resumes. A chunk lost with its Dask workers stops the run (:class:`PatternshopError`).
    ``folder`` may be an fsspec URL (:mod:`data_gen.storage`). ``description`` is written to ``folder/config.json``.
    The result also holds ``computed_now``: how many items this call computed rather than read.
    """
    folder = as_path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_text_atomic(folder / "config.json", json.dumps(description, indent=2, default=str))
    paths = [folder / f"chunk-{number:04d}.npz" for number in range(len(chunks))]
    missing = [(number, items) for number, items in enumerate(chunks) if not paths[number].exists()]
    total = sum(len(items) for items in chunks)
    done = total - sum(len(items) for _, items in missing)
    with tqdm(total=total, initial=done, desc=label, unit="exemplar", smoothing=0.05) as progress:
        for outcome in executor.map_unordered(functools.partial(_indexed, make_chunk), missing, in_process=False):
            if isinstance(outcome, Lost):
                raise PatternshopError(f"{label} chunk {outcome.task[0]} lost with its workers: {outcome.error}")
            number, result = outcome
            write_atomic(paths[number], functools.partial(np.savez, **result))
            progress.update(len(chunks[number]))
    parts = []
    for path in paths:
        with path.open("rb") as handle, np.load(handle) as data:
            parts.append(dict(data))
    corpus = {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}
    corpus["computed_now"] = np.int64(total - done)
    return corpus
