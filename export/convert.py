"""Batch conversion of folders: point files to maps (ONNX Runtime) and maps to point files (the synthesiser).

Both never stop at a bad file: every input gets a :class:`FileResult` (written;
skipped because its output exists; or failed, with a one-line reason) for the
caller to report. Outputs are written atomically, named after the input
(``NAME.txt`` -> ``NAME.tif``; maps, channel-PNG triplets included, -> ``NAME.txt``).

* :func:`convert_points`: worker processes read and rasterise point files
  (:func:`export.runtime.pattern_raster`); this process runs the network on
  batches of rasters of one size (:class:`~export.runtime.OnnxModel`), crops each
  output to its domain (:func:`~export.runtime.output_to_map`) and writes a CIELAB TIFF.
* :func:`resynthesize_maps`: worker processes read maps and synthesise points
  (:func:`synthesis.synthesize.synthesize`).

Workers are spawned processes (no forked torch or ONNX Runtime thread state);
``workers <= 1`` works in the calling process.
"""

from __future__ import annotations

import functools
import itertools
import multiprocessing
import os
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from synthesis.errors import PatternshopError, PatternshopWarning
from synthesis.labmap import POINTS_PER_INK
from synthesis.points import NPY_SUFFIX, TEXT_SUFFIXES, read_points

if TYPE_CHECKING:
    from export.runtime import OnnxModel

WRITTEN, SKIPPED, FAILED = "written", "skipped", "failed"

PathLike = str | os.PathLike


@dataclass(frozen=True)
class FileResult:
    """What happened to one input: ``status`` is written, skipped (the output existed) or failed (``error`` says why)."""

    source: Path
    output: Path
    status: str
    error: str | None = None
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class SynthesisSettings:
    """How :func:`resynthesize_maps` synthesises each map (see :func:`synthesis.synthesize.synthesize`)."""

    points: int | None = None  # None: points_per_ink x mean density
    points_per_ink: float | None = None  # None: synthesis.synthesize.POINTS_PER_INK
    schedule: str = "fast"
    iterations: int | None = None
    seed: int = 0
    palette: str | None = None  # None: the shipped palette


@dataclass(frozen=True)
class _Job:
    index: int
    source: Path
    output: Path


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _files(folder: PathLike, suffixes: tuple[str, ...]) -> list[Path]:
    folder = Path(folder)
    if not folder.is_dir():
        raise PatternshopError(f"{folder}: no such folder")
    return sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in suffixes)


def point_files(folder: PathLike) -> list[Path]:
    """The point files (.txt, .csv, .xy, .pts, .npy) directly in ``folder``, sorted."""
    return _files(folder, TEXT_SUFFIXES + (NPY_SUFFIX,))


def map_files(folder: PathLike) -> list[Path]:
    """The maps directly in ``folder``, sorted: TIFFs, sRGB images, and each channel-PNG triplet once (as NAME.L.png)."""
    from synthesis.mapio import SRGB_SUFFIXES, TIFF_SUFFIXES, channel_paths, is_channel_path

    maps = {channel_paths(p)[0] if is_channel_path(p) else p for p in _files(folder, TIFF_SUFFIXES + SRGB_SUFFIXES)}
    return sorted(maps)


def _stem(source: Path) -> str:
    """Output name of an input: ``face.L.png`` -> ``face``, ``pts.txt`` -> ``pts``."""
    from synthesis.mapio import is_channel_path

    return source.name[: -len(".L.png")] if is_channel_path(source) else source.stem


def _plan(sources: Sequence[PathLike], out_dir: PathLike, suffix: str, overwrite: bool) -> tuple[list[_Job], dict[int, FileResult]]:
    """Jobs to run, and the results already known (skipped: output exists; failed: two inputs, one output)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs: list[_Job] = []
    known: dict[int, FileResult] = {}
    claimed: dict[Path, Path] = {}
    for index, source in enumerate(map(Path, sources)):
        output = out_dir / (_stem(source) + suffix)
        if output in claimed:
            known[index] = FileResult(source, output, FAILED, f"{output} is made from {claimed[output]} already")
        elif output.exists() and not overwrite:
            known[index] = FileResult(source, output, SKIPPED)
        else:
            jobs.append(_Job(index, source, output))
        claimed.setdefault(output, source)
    return jobs, known


def _run(function: Callable, jobs: list, workers: int, window: int, initializer: Callable | None = None,
         initargs: tuple = ()) -> Iterator:
    """``function(job)`` for every job, in order of completion: in ``workers`` spawned processes with at most
    ``window`` jobs pending, or in this process (after ``initializer(*initargs)``) when workers <= 1 or one job."""
    workers = min(workers, len(jobs))
    if workers <= 1:
        if initializer is not None:
            initializer(*initargs)
        yield from map(function, jobs)
        return
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=initializer, initargs=initargs) as pool:
        queue = iter(jobs)
        running = {pool.submit(function, job) for job in itertools.islice(queue, max(window, workers))}
        while running:
            done, running = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                running.update(pool.submit(function, job) for job in itertools.islice(queue, 1))
                yield future.result()


# --- points -> maps -----------------------------------------------------------
def _load_points(raster_size: int, trained_points_per_ink: float | None, points_per_ink: float,
                 job: _Job) -> tuple[_Job, np.ndarray | str, tuple[float, float], float, int]:
    """(job, raster (S, S) or the error, domain, pixels per unit, point count) of one point file."""
    from export.runtime import pattern_raster

    try:
        points = read_points(job.source)
        raster, scale = pattern_raster(points, raster_size, trained_points_per_ink, points_per_ink)
    except (PatternshopError, OSError) as exc:
        return job, _one_line(exc), (1.0, 1.0), 0.0, 0
    return job, raster, points.domain, scale, len(points)


def convert_points(sources: Sequence[PathLike], out_dir: PathLike, model: OnnxModel, batch_size: int = 8,
                   workers: int = 2, bits: int = 16, overwrite: bool = False, progress: bool = False,
                   points_per_ink: float = POINTS_PER_INK) -> list[FileResult]:
    """Infer a map for each point file into ``out_dir/NAME.tif`` (``bits``-bit CIELAB); one result per source, in order.

    Args:
        model: the :class:`~export.runtime.OnnxModel` (its thread count applies to the batches).
        batch_size: rasters per network run (consecutive files whose rasters have one size).
        workers: processes reading and rasterising the point files.
        overwrite: replace existing outputs (default: skip their inputs).
        points_per_ink: points of a fully dark map at the patterns' scale (see :func:`export.runtime.points_to_map`).
    """
    from export.runtime import map_width, output_to_map, saturation_warning
    from synthesis.mapio import write_tiff

    if batch_size < 1 or bits not in (8, 16):
        raise PatternshopError(f"batch size must be >= 1 and bits 8 or 16, got {batch_size} and {bits}")
    jobs, results = _plan(sources, out_dir, ".tif", overwrite)
    batch: list[tuple[_Job, np.ndarray, tuple[float, float], float, int]] = []
    with tqdm(total=len(sources), initial=len(results), desc="convert", unit="file", disable=not progress) as bar:
        def run_batch() -> None:
            maps = model.predict(np.stack([raster for _, raster, _, _, _ in batch])[:, None])
            for (job, _, domain, scale, count), output in zip(batch, maps, strict=True):
                message = saturation_warning(count, points_per_ink)
                notes = (f"{job.source}: {message}",) if message else ()
                try:
                    write_tiff(output_to_map(output, domain, scale, map_width(domain, model, None)), job.output, bits)
                    results[job.index] = FileResult(job.source, job.output, WRITTEN, None, notes)
                except (PatternshopError, OSError) as exc:
                    results[job.index] = FileResult(job.source, job.output, FAILED, _one_line(exc), notes)
                bar.update()
            batch.clear()

        loader = functools.partial(_load_points, model.raster_size, model.points_per_ink, points_per_ink)
        for job, raster, domain, scale, count in _run(loader, jobs, workers, window=2 * workers + batch_size):
            if isinstance(raster, str):
                results[job.index] = FileResult(job.source, job.output, FAILED, raster)
                bar.update()
                continue
            if batch and raster.shape != batch[0][1].shape:
                run_batch()
            batch.append((job, raster, domain, scale, count))
            if len(batch) == batch_size:
                run_batch()
        if batch:
            run_batch()
    return [results[i] for i in range(len(sources))]


# --- maps -> points -----------------------------------------------------------
def _set_torch_threads(threads: int) -> None:
    import torch

    torch.set_num_threads(threads)


def _resynthesize(settings: SynthesisSettings, job: _Job) -> tuple[int, FileResult]:
    """Synthesise one map into its point file -> (job index, result); warnings come back in the result."""
    from synthesis.mapio import read_map
    from synthesis.palette import load_palette
    from synthesis.points import write_points
    from synthesis.synthesize import POINTS_PER_INK, point_count, synthesize

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PatternshopWarning)
        try:
            lab_map = read_map(job.source)
            points_per_ink = settings.points_per_ink if settings.points_per_ink is not None else POINTS_PER_INK
            n = settings.points if settings.points is not None else point_count(lab_map, points_per_ink)
            result = synthesize(lab_map, n=n, palette=load_palette(settings.palette), schedule=settings.schedule,
                                iterations=settings.iterations, seed=settings.seed)
            write_points(result.points, job.output)
            status, error = WRITTEN, None
        except (PatternshopError, OSError) as exc:
            status, error = FAILED, _one_line(exc)
    notes = tuple(" ".join(str(w.message).split()) for w in caught if issubclass(w.category, PatternshopWarning))
    return job.index, FileResult(job.source, job.output, status, error, notes)


def resynthesize_maps(sources: Sequence[PathLike], out_dir: PathLike, settings: SynthesisSettings = SynthesisSettings(),
                      workers: int = 2, threads: int = 1, overwrite: bool = False, progress: bool = False) -> list[FileResult]:
    """Synthesise points for each map into ``out_dir/NAME.txt``; one result per source, in order.

    Args:
        settings: point count, schedule, seed (each map uses the same seed) and palette.
        workers: synthesising processes, each with ``threads`` torch threads.
        overwrite: replace existing outputs (default: skip their inputs).
    """
    import torch

    if threads < 1:
        raise PatternshopError(f"threads must be at least 1, got {threads}")
    jobs, results = _plan(sources, out_dir, ".txt", overwrite)
    caller_threads = torch.get_num_threads()
    try:
        with tqdm(total=len(sources), initial=len(results), desc="resynthesize", unit="map", disable=not progress) as bar:
            for index, result in _run(functools.partial(_resynthesize, settings), jobs, workers, window=2 * workers,
                                      initializer=_set_torch_threads, initargs=(threads,)):
                results[index] = result
                bar.update()
    finally:  # in-process work set this process's torch threads
        torch.set_num_threads(caller_threads)
    return [results[i] for i in range(len(sources))]
