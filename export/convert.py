"""Batch conversion of folders: point files to maps (ONNX Runtime) and maps to point files (the synthesiser).

Both never stop at a bad file: every input gets a :class:`FileResult` (written;
skipped because its output exists; or failed, with a one-line reason) for the
caller to report. Outputs are written atomically, named after the input
(``NAME.txt`` -> ``NAME.tif``; maps, channel-PNG triplets included, -> ``NAME.txt``).

* :func:`convert_points`: each worker process loads the network once
  (:class:`~export.runtime.OnnxModel`), then takes chunks of point files: reads
  each and infers its map as ``infer`` does (:func:`export.runtime.infer_map`,
  scale chosen from the pattern unless given; but
  :attr:`~export.infer_config.InferConfig.convert_symmetries` readings per map, one, where ``infer``
  averages more) and writes a CIELAB TIFF. Files go to the workers one or a few
  at a time (:func:`_chunks`), so that they end together. For a 20k-point file
  at 41,912 points per ink (a 704 x 704 px raster: 586 px of domain and the
  mirrored border) v18 (``l_scale`` and a full-resolution
  path on 4 x 4 blocks) reads the file once: about 0.15 s of one core, of which
  the network 0.10 s, the smoothing 0.011 s (float32 matrix Gaussians,
  :mod:`export.gaussian`; 0.023 s through the FFT), writing 0.007 s, reading
  0.005 s, the degeneracy check 0.005 s, the water-filling 0.001 s
  (``bench/bench_infer.py``, section 3, 2026-11-28 01:36 UTC, an idle machine);
  the shipped v19 (its correlation decoder with an encoder of its own, stopped
  at S/4) 0.154 s, the network 0.108 s; a model without ``l_scale`` the same,
  less the smoothing. Each worker starts in about 0.3 s of one core (imports
  without scipy or tqdm, the ONNX session); on this project's 2-core machine two
  workers convert 10.9-11.2 files a second with v18 and 10.7-11.3 with v19 in
  that run; the machine's speed moves by tens of percent between hours (8-10
  files/s in other runs; MODEL_CARD.md, "Cost").
* :func:`resynthesize_maps`: worker processes read maps and synthesise points
  (:func:`synthesis.synthesize.synthesize`), one map per task.

Folders may be local paths or fsspec URLs (``file://``, ``s3://``, ``gs://`` with the user's backend, ``memory://``;
:mod:`data_gen.storage`): a worker downloads its remote inputs into a temporary folder, reads them there, and
uploads each output in one request once it is complete (no half file on a kill), so errors name the URLs.
``memory://`` lives in one process: with it the local back end works in the calling process (``workers`` 1).

Workers are spawned processes (no forked ONNX Runtime or numba thread state)
that ignore Ctrl+C: the parent terminates them at once on any exception, Ctrl+C
included, and removes the temporary files they leave; ``workers <= 1`` works in
the calling process. With ``scheduler`` (a Dask scheduler's address) the files
go to that cluster's workers instead (:mod:`data_gen.executor`): Ctrl+C cancels
what has not started, and a file whose worker died twice fails with Dask's reason.
"""

from __future__ import annotations

import functools
import math
import os
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from data_gen.executor import DASK, LOCAL, Executor, Lost
from data_gen.storage import StoragePath, as_path, in_process, is_local, local_copies, local_target
from export.infer_config import DEFAULT_INFER, InferConfig
from synthesis.atomic import check_writable, remove_stale_temporaries
from synthesis.conventions import POINTS_PER_INK
from synthesis.errors import PatternshopError, PatternshopWarning
from synthesis.points import NPY_SUFFIX, TEXT_SUFFIXES, read_points

if TYPE_CHECKING:
    from export.runtime import OnnxModel

WRITTEN, SKIPPED, FAILED = "written", "skipped", "failed"

PathLike = str | os.PathLike


@dataclass(frozen=True)
class FileResult:
    """What happened to one input: ``status`` is written, skipped (the output existed) or failed (``error`` says why)."""

    source: StoragePath  # a Path, or a UPath for a URL (data_gen.storage.as_path)
    output: StoragePath
    status: str
    error: str | None = None
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class SynthesisSettings:
    """How :func:`resynthesize_maps` synthesises each map (see :func:`synthesis.synthesize.synthesize`)."""

    points: int | None = None  # None: points_per_ink x area x mean density (synthesis.synthesize.point_count)
    points_per_ink: float | None = None  # None: synthesis.synthesize.POINTS_PER_INK
    schedule: str = "fast"
    iterations: int | None = None
    seed: int = 0
    palette: str | None = None  # None: the shipped palette


@dataclass(frozen=True)
class _Job:
    index: int
    source: StoragePath
    output: StoragePath


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _files(folder: PathLike, suffixes: tuple[str, ...]) -> list[StoragePath]:
    folder = as_path(folder)
    if not folder.is_dir():
        raise PatternshopError(f"{folder}: no such folder")
    return sorted((p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in suffixes),
                  key=str)


def point_files(folder: PathLike) -> list[StoragePath]:
    """The point files (.txt, .csv, .xy, .pts, .npy) directly in ``folder`` (a path or an fsspec URL), sorted."""
    return _files(folder, TEXT_SUFFIXES + (NPY_SUFFIX,))


def map_files(folder: PathLike) -> list[StoragePath]:
    """The maps directly in ``folder`` (a path or an fsspec URL), sorted: TIFFs, sRGB images, and each channel-PNG
    triplet once (as NAME.L.png)."""
    from synthesis.mapio import SRGB_SUFFIXES, TIFF_SUFFIXES

    return sorted({_inputs(p)[0] for p in _files(folder, TIFF_SUFFIXES + SRGB_SUFFIXES)}, key=str)


def _inputs(source: StoragePath) -> list[StoragePath]:
    """The files an input is read from: itself, or for one of a channel-PNG triplet the three (NAME.L.png first)."""
    from synthesis.mapio import channel_paths, is_channel_path

    return [source.with_name(p.name) for p in channel_paths(source.name)] if is_channel_path(source.name) else [source]


def _stem(source: StoragePath) -> str:
    """Output name of an input: ``face.L.png`` -> ``face``, ``pts.txt`` -> ``pts``."""
    from synthesis.mapio import is_channel_path

    return source.name[: -len(".L.png")] if is_channel_path(source.name) else source.stem


def _plan(sources: Sequence[PathLike], out_dir: PathLike, suffix: str, overwrite: bool,
          absolute: bool = False) -> tuple[list[_Job], dict[int, FileResult]]:
    """Jobs to run, and the results already known (skipped: output exists; failed: two inputs, one output).

    ``absolute``: jobs and results name absolute paths (for workers on other machines, whose working folder differs).
    """
    out_dir = as_path(out_dir)
    out_dir = out_dir.absolute() if absolute and is_local(out_dir) else out_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs: list[_Job] = []
    known: dict[int, FileResult] = {}
    claimed: dict[StoragePath, StoragePath] = {}
    for index, source in enumerate(map(as_path, sources)):
        source = source.absolute() if absolute and is_local(source) else source
        output = out_dir / (_stem(source) + suffix)
        if output in claimed:
            known[index] = FileResult(source, output, FAILED, f"{output} is made from {claimed[output]} already")
        elif output.exists() and not overwrite:
            known[index] = FileResult(source, output, SKIPPED)
        else:
            jobs.append(_Job(index, source, output))
        claimed.setdefault(output, source)
    if jobs and is_local(out_dir):
        check_writable(jobs[0].output)  # an unwritable folder stops the run before any work, not file by file
    return jobs, known


def _run(function: Callable, tasks: list, executor: Executor, out_dir: StoragePath, lost: Callable[[Lost], object],
         initializer: Callable | None = None, initargs: tuple = ()) -> Iterator:
    """``function(task)`` for every task through ``executor`` (:mod:`data_gen.executor`), in order of completion;
    a task lost with its Dask workers comes back as ``lost(Lost)``.

    An exception here (Ctrl+C included) stops the workers (local: terminated at once; Dask: futures cancelled);
    the temporary files that terminated local workers leave are removed from ``out_dir``.
    """
    try:
        for result in executor.map_unordered(function, tasks, initializer, initargs):
            yield lost(result) if isinstance(result, Lost) else result
    finally:
        if executor.kind == LOCAL and is_local(out_dir):  # remote workers may still be writing theirs (atomically)
            remove_stale_temporaries(out_dir)


def _executor(workers: int, scheduler: str | None) -> Executor:
    """``scheduler``: a Dask scheduler's address (``tcp://host:8786``): the files are converted on its workers, which
    must read the inputs and write ``out_dir`` at the same absolute paths (a shared file system) or URLs; None
    (default): ``workers`` local processes (:mod:`data_gen.executor`)."""
    return Executor(DASK, workers, scheduler) if scheduler else Executor(LOCAL, workers)


def _processes(workers: int, tasks: int, scheduler: str | None, jobs: list[_Job]) -> int:
    """Worker processes for ``tasks`` tasks: at most ``workers``; 1 (this process) for ``memory://`` files and no
    ``scheduler``, since other processes would see an empty ``memory://``."""
    if not scheduler and any(in_process(job.source) or in_process(job.output) for job in jobs):
        return 1
    return max(1, min(workers, tasks))


def _check_share(job: _Job, needed: float, work: str, share: float) -> None:
    """Fail one file (not the run) whose estimated memory exceeds its process's share of the limit."""
    if needed > share:
        raise PatternshopError(f"{job.source}: {work} needs about {needed / 1e9:.3g} GB, over this process's share "
                               f"{share / 1e9:.3g} GB of --max-memory-gb")


# --- points -> maps -----------------------------------------------------------
_WORKER_MODEL: OnnxModel | None = None  # the network of a convert_points worker process, loaded once


def _load_model(path: Path | None, threads: int) -> None:
    """Worker start: load the network (``path`` None: the shipped model) with ``threads`` ONNX Runtime threads."""
    global _WORKER_MODEL
    from export.runtime import OnnxModel

    _WORKER_MODEL = OnnxModel(path, threads=threads)


@dataclass(frozen=True)
class _InferenceSettings:
    points_per_ink: float | None  # None: per file (export.evidence.pattern_scale: the header's, else chosen)
    bits: int
    memory_limit: float  # bytes one process may use for one file
    symmetries: int  # readings averaged per file (export.runtime.predict_symmetric)
    denoise: bool  # L smoothed within l_scale (export.runtime.infer_map; a model without it: never)
    config: InferConfig  # the constants around the network


BALANCE_TASKS = 16  # tasks per worker process at least, while there are files: the workers end together


def _chunks(jobs: list[_Job], batch_size: int, processes: int) -> list[list[_Job]]:
    """The jobs in tasks of at most ``batch_size`` files, smaller in a short run: at least :data:`BALANCE_TASKS` per
    process while there are files, so that no worker idles at the end while another converts a whole batch (40 files
    in batches of 8 on 2 workers went 24 to one worker and 16 to the other)."""
    size = max(1, min(batch_size, len(jobs) // (BALANCE_TASKS * processes)))
    return [jobs[i : i + size] for i in range(0, len(jobs), size)]


def _convert_chunk(settings: _InferenceSettings, chunk: list[_Job], model: OnnxModel | None = None) -> list[tuple[int, FileResult]]:
    """Infer and write the map of each point file of a chunk -> (job index, result) pairs.

    One raster per network run: on the CPU a batch of 8 took as long per raster or longer (68-89 ms vs 68-74 ms).
    """
    from export.evidence import pattern_scale
    from export.runtime import infer_map, map_width, raster_scale
    from synthesis.mapio import write_tiff
    from synthesis.resources import inference_bytes

    model = model if model is not None else _WORKER_MODEL
    results: list[tuple[int, FileResult]] = []
    for job in chunk:
        notes: tuple[str, ...] = ()
        named = str  # error messages as they are, unless they name local copies of remote files
        try:
            with local_copies([job.source]) as copies:
                named = copies.named
                points = read_points(copies.paths[0])
            scale = pattern_scale(points, settings.points_per_ink, settings.config)
            (w, h), (_, side) = points.domain, raster_scale(points.domain, model.raster_size, model.points_per_ink,
                                                            scale.points_per_ink, settings.config.border_px)
            width = map_width(points.domain, model, None)
            _check_share(job, inference_bytes(side, width * max(1, round(width * h / w))), f"a {side}x{side} px raster",
                         settings.memory_limit)
            with warnings.catch_warnings(record=True) as caught:  # the saturation warning of a given scale
                warnings.simplefilter("always", PatternshopWarning)
                inference = infer_map(points, model, scale=scale, symmetries=settings.symmetries, denoise=settings.denoise,
                                      config=settings.config)
            notes = tuple(f"{job.source}: {warning.message}" for warning in caught)
            if scale.automatic and scale.points_per_ink != POINTS_PER_INK:  # a guess; not the header's or the user's
                notes += (f"{job.source}: read at {scale.describe()}",)
            with local_target(job.output) as output:
                write_tiff(inference.lab_map, output, settings.bits)
            results.append((job.index, FileResult(job.source, job.output, WRITTEN, None, notes)))
        except (PatternshopError, OSError) as exc:
            results.append((job.index, FileResult(job.source, job.output, FAILED, named(_one_line(exc)), notes)))
    return results


def convert_points(sources: Sequence[PathLike], out_dir: PathLike, model: OnnxModel, batch_size: int = 8,
                   workers: int = 2, bits: int = 16, overwrite: bool = False, progress: bool = False,
                   points_per_ink: float | None = None, memory_limit: float = math.inf, symmetries: int | None = None,
                   denoise: bool = True, scheduler: str | None = None, config: InferConfig = DEFAULT_INFER) -> list[FileResult]:
    """Infer a map for each point file into ``out_dir/NAME.tif`` (``bits``-bit CIELAB); one result per source, in order.

    Args:
        model: the :class:`~export.runtime.OnnxModel` (each worker loads its file with its thread count).
        batch_size: point files per worker task at most (fewer in a short run, :func:`_chunks`).
        workers: processes, each doing the whole work for its files (1: this process).
        overwrite: replace existing outputs (default: skip their inputs).
        points_per_ink: points per unit area of full ink at the patterns' scale; None takes it per file as ``infer``
            does (:func:`export.evidence.pattern_scale`: the file's header, else chosen from the points).
        memory_limit: bytes all workers together may use; a file whose estimate exceeds its worker's share fails.
        symmetries: readings averaged per file (:func:`export.runtime.predict_symmetric`), one network pass
            each; None: ``config.convert_symmetries`` (1, for throughput).
        denoise: smooth L within its predicted uncertainty as ``infer`` does (a model without ``l_scale``:
            never); False keeps the detail.
        scheduler: see :func:`_executor`.
        config: the constants around the network (:class:`export.infer_config.InferConfig`).
    """
    if batch_size < 1 or bits not in (8, 16):
        raise PatternshopError(f"batch size must be >= 1 and bits 8 or 16, got {batch_size} and {bits}")
    jobs, results = _plan(sources, out_dir, ".tif", overwrite, absolute=scheduler is not None)
    processes = _processes(workers, math.ceil(len(jobs) / batch_size), scheduler, jobs)
    settings = _InferenceSettings(points_per_ink, bits, memory_limit / processes,
                                  config.convert_symmetries if symmetries is None else symmetries, denoise, config)
    chunks = _chunks(jobs, batch_size, processes)
    executor = _executor(processes, scheduler)
    if processes <= 1 and executor.kind == LOCAL:
        convert, initializer, initargs = functools.partial(_convert_chunk, settings, model=model), None, ()
    else:  # the shipped model by name: a remote worker finds it in its own installation
        from export.runtime import DEFAULT_MODEL

        model_file = None if model.path == DEFAULT_MODEL else model.path
        convert, initializer, initargs = functools.partial(_convert_chunk, settings), _load_model, (model_file, model.threads)

    def lost(chunk: Lost) -> list[tuple[int, FileResult]]:
        return [(job.index, FileResult(job.source, job.output, FAILED, chunk.error)) for job in chunk.task]

    from tqdm import tqdm  # here: the workers import this module, and tqdm's import is 40 ms of their start

    with tqdm(total=len(sources), initial=len(results), desc="convert", unit="file", disable=not progress) as bar:
        for chunk_results in _run(convert, chunks, executor, as_path(out_dir), lost, initializer, initargs):
            results.update(chunk_results)
            bar.update(len(chunk_results))
    return [results[i] for i in range(len(sources))]


# --- maps -> points -----------------------------------------------------------
def _resynthesize(settings: SynthesisSettings, threads: int, memory_limit: float, job: _Job) -> tuple[int, FileResult]:
    """Synthesise one map into its point file -> (job index, result); warnings come back in the result."""
    from synthesis.mapio import map_size, read_map
    from synthesis.palette import load_palette
    from synthesis.points import write_points
    from synthesis.resources import synthesis_bytes
    from synthesis.synthesize import point_count, synthesize

    named = str  # messages as they are, unless they name local copies of remote files
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PatternshopWarning)
        try:
            with local_copies(_inputs(job.source)) as copies:
                named = copies.named
                width, height = map_size(copies.paths[0])
                _check_share(job, synthesis_bytes(width * height, settings.points or 0), f"a {width}x{height} px map",
                             memory_limit)
                lab_map = read_map(copies.paths[0])
            points_per_ink = settings.points_per_ink if settings.points_per_ink is not None else POINTS_PER_INK
            n = settings.points if settings.points is not None else point_count(lab_map, points_per_ink)
            _check_share(job, synthesis_bytes(width * height, n), f"{n:,} points", memory_limit)
            result = synthesize(lab_map, n=n, palette=load_palette(settings.palette), schedule=settings.schedule,
                                iterations=settings.iterations, seed=settings.seed, threads=threads)
            with local_target(job.output) as output:
                write_points(result.points, output)
            status, error = WRITTEN, None
        except (PatternshopError, OSError) as exc:
            status, error = FAILED, named(_one_line(exc))
    notes = tuple(named(" ".join(str(w.message).split())) for w in caught if issubclass(w.category, PatternshopWarning))
    return job.index, FileResult(job.source, job.output, status, error, notes)


def resynthesize_maps(sources: Sequence[PathLike], out_dir: PathLike, settings: SynthesisSettings = SynthesisSettings(),
                      workers: int = 2, threads: int = 1, overwrite: bool = False, progress: bool = False,
                      memory_limit: float = math.inf, scheduler: str | None = None) -> list[FileResult]:
    """Synthesise points for each map into ``out_dir/NAME.txt``; one result per source, in order.

    Args:
        settings: point count, schedule, seed (each map uses the same seed) and palette.
        workers: synthesising processes (1: this process), each with ``threads`` threads.
        overwrite: replace existing outputs (default: skip their inputs).
        memory_limit: bytes all workers together may use; a map whose estimate exceeds its worker's share fails.
        scheduler: see :func:`_executor`.
    """
    if threads < 1:
        raise PatternshopError(f"threads must be at least 1, got {threads}")
    jobs, results = _plan(sources, out_dir, ".txt", overwrite, absolute=scheduler is not None)
    processes = _processes(workers, len(jobs), scheduler, jobs)
    synthesise = functools.partial(_resynthesize, settings, threads, memory_limit / processes)

    def lost(job: Lost) -> tuple[int, FileResult]:
        return job.task.index, FileResult(job.task.source, job.task.output, FAILED, job.error)

    from tqdm import tqdm

    with tqdm(total=len(sources), initial=len(results), desc="resynthesize", unit="map", disable=not progress) as bar:
        for index, result in _run(synthesise, jobs, _executor(processes, scheduler), as_path(out_dir), lost):
            results[index] = result
            bar.update()
    return [results[i] for i in range(len(sources))]
