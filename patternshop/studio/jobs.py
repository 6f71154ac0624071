"""Synthesis off the event loop: one worker thread at a time, cancellable, publishing points as they form.

:class:`Synthesizer` runs :func:`patternshop.api.synthesize` on a snapshot of the project's map. Its
per-iteration callback publishes a *frame* (a copy of the current positions) at the start (the
density-matched start, a usable preview), then at most every :data:`FRAME_INTERVAL` seconds, and the final
points; each frame has a number that only grows, so the page asks for "frames since F". Starting another
synthesis or editing the map cancels the running one at its next iteration.

The first points are there before the request that starts a synthesis is answered: :meth:`Synthesizer.start`
publishes a quick preview (:func:`preview_points`: independent points with probability proportional to the
density, a few milliseconds) while the synthesis sets itself up (its fields and stratified start take 0.3 to
0.9 s). :meth:`Synthesizer.warm_up` (called by the server at start, in a background thread) imports the
synthesiser, loads the palette and runs a tiny synthesis so that the first real one pays no import or kernel
loading (about 1 s).

After an edit, a synthesis with the same seed and point setting as the last finished one is *local*
(:mod:`patternshop.studio.incremental`): the points away from what changed since then stay, new ones are drawn
in the changed region, and the synthesiser warm-starts on a window around it; its first frame (the kept and the
new points) is published at once, as the preview is for a full synthesis.
"""

from __future__ import annotations

import itertools
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from patternshop.studio.incremental import Base, LocalUpdate, plan_local_update
from patternshop.studio.project import Project
from synthesis.errors import PatternshopError
from synthesis.resources import synthesis_bytes

FRAME_INTERVAL = 0.1  # seconds between published frames while a synthesis runs
GIGABYTE = 1e9


def preview_points(lab: np.ndarray, n: int, seed: int) -> np.ndarray:
    """(n, 2) independent points with probability proportional to the density ``1 - L/100`` of the (H, W, 3)
    map (uniform within a pixel), in map units: the preview shown while the synthesis sets itself up.

    A cumulative sum and a sorted search (about 15 ms for 20,000 points on a 1024 x 1024 map); a white map
    gives uniform points.
    """
    height, width = lab.shape[:2]
    side = max(height, width)
    cumulative = np.cumsum(np.clip(1.0 - lab[..., 0].astype(np.float64).reshape(-1) / 100.0, 0.0, 1.0))
    rng = np.random.default_rng(seed)
    if cumulative[-1] <= 0:
        pixel = rng.integers(0, height * width, n)
    else:
        pixel = np.minimum(np.searchsorted(cumulative, rng.random(n) * cumulative[-1], side="right"), height * width - 1)
    row, col = np.divmod(pixel, width)
    xy = (np.stack([col, row], axis=1) + rng.random((n, 2))) / side
    return np.minimum(xy, np.array([width / side, height / side]) * (1 - 1e-9))


class _Cancelled(Exception):
    """Raised inside the synthesis callback to stop a cancelled job."""


@dataclass
class Job:
    """One synthesis run."""

    id: int
    version: int  # the map version it synthesises
    n: int
    seed: int
    total: int
    cancel: threading.Event = field(default_factory=threading.Event)
    state: str = "running"  # running, done, cancelled, error
    iteration: int = 0
    message: str = ""
    started: float = field(default_factory=time.perf_counter)
    seconds: float = 0.0
    first_points_seconds: float | None = None
    lab: np.ndarray | None = field(default=None, repr=False)  # the map it synthesises (the next run's base)
    count_key: tuple = ()  # what decided n: ("points", n) or ("ink", points_per_ink)
    local: dict[str, Any] | None = None  # a local update: changed_share, window_share, window_points, drawn


@dataclass
class Frame:
    number: int
    job: int
    version: int
    iteration: int
    total: int
    final: bool
    xy: np.ndarray
    domain: tuple[float, float]
    preview: bool = False  # the quick density sample published before the synthesis's own start


class Synthesizer:
    """Runs syntheses of a project's map in worker threads (one at a time)."""

    def __init__(self, project: Project, max_memory_gb: float = 4.0,
                 on_change: Callable[[], None] | None = None) -> None:
        """``on_change()`` is called (from any thread, without the lock held) after a frame is published or a
        job's state changes: the server's event streams wake on it."""
        self.project = project
        self.max_memory_gb = max_memory_gb
        self.on_change = on_change or (lambda: None)
        self.lock = threading.Lock()
        self.job: Job | None = None
        self.frame: Frame | None = None
        self._ids = itertools.count(1)
        self._frames = itertools.count(1)
        self._threads: list[threading.Thread] = []
        self._warm_thread: threading.Thread | None = None
        self._warm_now = threading.Event()
        self.base: Base | None = None  # the last finished synthesis, where a local one starts from
        self._load_saved_points()

    def _load_saved_points(self) -> None:
        path = self.project.points_path()
        if path is None or not path.exists():
            return
        from synthesis.points import read_points

        try:
            points = read_points(path)
        except PatternshopError:
            return
        info = self.project.state["points"]
        self.frame = Frame(next(self._frames), 0, int(info.get("version", -1)), int(info.get("iterations", 0)),
                           int(info.get("iterations", 0)), True, points.xy, points.domain)
        if self.project.has_map and info.get("version") == self.project.version and "count_key" in info:
            self.base = Base(self.project.current()[0], points.xy, int(info["seed"]), tuple(info["count_key"]))

    # --- control -----------------------------------------------------------------------------------------
    def start(self, points: int | None = None, seed: int | None = None, iterations: int | None = None) -> dict[str, Any]:
        """Cancel any running synthesis and start one of the current map; returns :meth:`status`.

        ``points``, ``seed`` default to the project's settings (points: ``points_per_ink`` x mean density).
        Without ``iterations``, a run after an edit is local when it can be (see the module docstring).

        Raises:
            PatternshopError: no map, a white map, a bad count or seed, or a run over ``max_memory_gb``.
        """
        from synthesis.labmap import LabMap
        from synthesis.synthesize import SCHEDULES, point_count, points_per_ink_of

        lab, version = self.project.current()
        settings = self.project.settings
        lab_map = LabMap(lab)
        if points is None:
            points = settings["points"]
        count_key = ("ink", float(settings["points_per_ink"])) if points is None else ("points", points)
        if points is None:
            points = point_count(lab_map, settings["points_per_ink"])
        if isinstance(points, bool) or not isinstance(points, int) or points < 2:
            raise PatternshopError(f"the point count must be an integer >= 2, got {points!r}")
        seed = settings["seed"] if seed is None else seed
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= 2**32 - 1:
            raise PatternshopError(f"the seed must be an integer from 0 to {2**32 - 1}, got {seed!r}")
        if iterations is not None and (isinstance(iterations, bool) or not isinstance(iterations, int) or not 0 <= iterations <= 100_000):
            raise PatternshopError(f"iterations must be an integer from 0 to 100000, got {iterations!r}")
        needed = synthesis_bytes(lab.shape[0] * lab.shape[1], points)
        if needed > self.max_memory_gb * GIGABYTE:
            raise PatternshopError(f"synthesising {points:,} points needs about {needed / GIGABYTE:.3g} GB of memory, over "
                                   f"the limit of {self.max_memory_gb:g} GB (fewer points, or restart the studio "
                                   "with a higher --max-memory-gb)")
        with self.lock:
            base = self.base
        local = None
        if iterations is None and base is not None and base.lab.shape == lab.shape:
            try:
                # the new map's count at the base's points per ink (a set count keeps its density per ink until the
                # next full run: a darker stroke gets more points, not fewer everywhere else)
                local_n = points if count_key[0] == "ink" else point_count(lab_map, points_per_ink_of(LabMap(base.lab),
                                                                                                       len(base.xy)))
                local = plan_local_update(base, lab, local_n, seed, count_key)
            except PatternshopError:  # not to be re-made locally (a white map...): the full synthesis says why, if anything
                local = None
        if local is not None:
            points, total = local.n, local.iterations
        else:
            total = iterations if iterations is not None else SCHEDULES["fast"].iterations
        with self.lock:
            if self.job is not None and self.job.state == "running":
                self.job.cancel.set()
                self.job.state, self.job.message = "cancelled", "replaced by a new synthesis"
            job = Job(next(self._ids), version, points, seed, total, lab=lab, count_key=count_key)
            self.job = job
        if local is None:
            self._publish(job, preview_points(lab, points, seed), 0, False, lab_map.domain, True)  # first points at once
            run = self._full_run(lab_map, points, seed, iterations)
        else:
            job.local = {"changed_share": round(local.changed_share, 5), "window_share": round(local.window_share, 5),
                         "window_points": len(local.start), "drawn": local.drawn}
            self._publish(job, np.concatenate([local.fixed, local.start]), 0, False, lab_map.domain, True)
            run = self._local_run(local, lab_map, seed)
        thread = threading.Thread(target=self._run, args=(job, run, lab_map.domain), name=f"synthesis-{job.id}", daemon=True)
        self._threads = [t for t in self._threads if t.is_alive()] + [thread]
        thread.start()
        return self.status()

    def warm_up(self, delay: float = 0.0) -> threading.Thread:
        """Import the synthesiser, load the palette and run a tiny synthesis (numba loads its compiled kernels
        once per process) in a background thread, after ``delay`` seconds or as soon as ``warm_up()`` is
        called again without a delay, so that the first synthesis the page asks for starts at once (about 1 s
        of work, kept out of the server's start and the page's load); once per synthesizer; returns the thread.
        Errors are ignored: the real synthesis will report them."""
        with self.lock:
            if self._warm_thread is not None:
                if delay <= 0:
                    self._warm_now.set()
                return self._warm_thread

            def run() -> None:
                self._warm_now.wait(delay)
                self._warm_up()

            self._warm_thread = threading.Thread(target=run, name="synthesis-warm-up", daemon=True)
        self._warm_thread.start()
        return self._warm_thread

    @staticmethod
    def _warm_up() -> None:
        try:
            from patternshop import api
            from synthesis.labmap import LabMap

            lab = np.zeros((24, 32, 3), np.float32)
            lab[..., 0] = 100.0  # white right half: the synthesis holds points in the ink
            lab[:, :16, 0] = 40.0
            api.synthesize(LabMap(lab), points=40, iterations=2)
        except Exception:  # noqa: BLE001 - only a warm-up
            pass

    def cancel(self, reason: str = "cancelled") -> bool:
        """Stop the running synthesis (at its next iteration); True when one was running."""
        with self.lock:
            job = self.job
            if job is None or job.state != "running":
                return False
            job.cancel.set()
            job.state, job.message = "cancelled", reason
        self.on_change()
        return True

    def wait(self, timeout: float = 60.0) -> None:
        """Wait until no worker thread runs (tests, shutdown)."""
        deadline = time.monotonic() + timeout
        for thread in list(self._threads):
            thread.join(max(0.0, deadline - time.monotonic()))

    # --- the worker --------------------------------------------------------------------------------------
    def _publish(self, job: Job, xy: np.ndarray, iteration: int, final: bool, domain: tuple[float, float],
                 preview: bool = False) -> None:
        with self.lock:
            if job.cancel.is_set():
                return
            self.frame = Frame(next(self._frames), job.id, job.version, iteration, job.total, final, xy, domain, preview)
            job.iteration = iteration
            if job.first_points_seconds is None:
                job.first_points_seconds = time.perf_counter() - job.started
        self.on_change()

    @staticmethod
    def _full_run(lab_map: Any, points: int, seed: int, iterations: int | None) -> Any:
        """A full synthesis as ``run(progress) -> (PointSet, iterations)``."""
        from patternshop import api

        def run(progress: Any) -> tuple[Any, int]:
            result = api.synthesize(lab_map, points=points, seed=seed, iterations=iterations, progress=progress)
            return result.points, result.iterations

        return run

    @staticmethod
    def _local_run(local: LocalUpdate, lab_map: Any, seed: int) -> Any:
        """A local update (the synthesiser warm-started on its window) as ``run(progress) -> (PointSet, iterations)``."""
        from synthesis.points import PointSet
        from synthesis.synthesize import points_per_ink_of

        def run(progress: Any) -> tuple[Any, int]:
            xy, iterations = local.run(seed, lambda done, frame: progress(done, local.iterations, frame))
            return PointSet(xy, lab_map.domain, points_per_ink=points_per_ink_of(lab_map, len(xy))), iterations

        return run

    def _run(self, job: Job, run: Any, domain: tuple[float, float]) -> None:
        """Run ``run(progress) -> (PointSet, iterations)`` for ``job``: publish its frames, save its points, make
        them the next base; errors end the job with a one-line message."""
        last = [0.0]

        def progress(done: int, total: int, xy: np.ndarray) -> None:
            if job.cancel.is_set():
                raise _Cancelled
            job.iteration = done
            now = time.perf_counter()
            if done == 0 or now - last[0] >= FRAME_INTERVAL:
                last[0] = now
                self._publish(job, xy.copy(), done, False, domain)

        try:
            points, iterations = run(progress)
        except _Cancelled:
            return
        except PatternshopError as exc:
            self._fail(job, " ".join(str(exc).split()))
            return
        except MemoryError:
            self._fail(job, "out of memory: use fewer points")
            return
        except Exception as exc:  # a bug: keep the studio usable, say what happened
            self._fail(job, f"internal error: {type(exc).__name__}: {' '.join(str(exc).split())}")
            return
        if job.cancel.is_set():
            return
        seconds = time.perf_counter() - job.started
        try:
            self.project.save_points(points, job.version, {"seed": job.seed, "iterations": iterations,
                                                           "seconds": round(seconds, 3), "count_key": list(job.count_key),
                                                           "local": job.local})
        except (PatternshopError, OSError) as exc:
            self._fail(job, f"points not saved: {exc}")
            return
        self._publish(job, points.xy, iterations, True, points.domain)
        with self.lock:
            if not job.cancel.is_set():
                job.state, job.seconds = "done", seconds
                self.base = Base(job.lab, points.xy, job.seed, job.count_key)
        self.on_change()

    def _fail(self, job: Job, message: str) -> None:
        with self.lock:
            if not job.cancel.is_set():
                job.state, job.message = "error", message
        self.on_change()

    # --- queries -----------------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """The running or last job: state, iteration, total, n, seconds, message."""
        with self.lock:
            job = self.job
            if job is None:
                return {"state": "idle"}
            return {"state": job.state, "job": job.id, "version": job.version, "n": job.n, "seed": job.seed,
                    "iteration": job.iteration, "total": job.total, "message": job.message,
                    "seconds": round(job.seconds if job.state == "done" else time.perf_counter() - job.started, 3),
                    "first_points_seconds": None if job.first_points_seconds is None else round(job.first_points_seconds, 3),
                    "local": job.local}

    def frame_since(self, since: int) -> Frame | None:
        """The newest frame if it is newer than frame number ``since``, else None."""
        with self.lock:
            frame = self.frame
        return frame if frame is not None and frame.number > since else None

    def latest_frame(self) -> Frame | None:
        with self.lock:
            return self.frame
