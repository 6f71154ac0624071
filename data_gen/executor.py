"""Where batch work runs: one interface, two back ends (pair generation, the palette corpus, ``patternshop convert``).

* ``local`` (the default): a pool of ``workers`` spawned processes on this
  machine (no forked torch, numba or ONNX Runtime thread state), each started
  once with the caller's initializer; ``workers <= 1`` runs in this process.
  Workers ignore Ctrl+C: the parent terminates them at once on any exception,
  Ctrl+C included. A worker killed from outside (out of memory) stops the
  run with an error (rerun to resume): use ``dask`` where workers may die.
* ``dask``: the workers of a Dask distributed cluster, reached through its
  scheduler's address (``tcp://host:8786``), or of a ``LocalCluster`` of
  ``workers`` processes started for the run when no address is given. Tasks
  that raise are retried once (``retries``); a task whose worker dies is
  rescheduled on another by Dask's scheduler, and when it has killed
  ``retries + 1`` workers it comes back as :class:`Lost` with Dask's error
  (a ``LocalCluster`` started here allows ``retries`` worker deaths; a running
  scheduler's own ``distributed.scheduler.allowed-failures`` applies, default 3).
  On an exception (Ctrl+C included) the run's futures are cancelled: a task
  already running on a remote worker finishes, and callers write atomically.

Results are the same on both: callers seed every task by its index, never by
the worker. The initializer runs once per worker process before its first task
(on Dask, once per process and initializer arguments, so runs with other
settings on a long-lived cluster re-initialise).
"""

from __future__ import annotations

import itertools
import logging
import multiprocessing
import queue
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

from synthesis.errors import PatternshopError

LOCAL, DASK = "local", "dask"
# Scheduler settings of a LocalCluster started here (a running scheduler: set them in its environment,
# docs/distributed.md): a worker holds only the tasks it runs, so that its death counts against those alone
SCHEDULER_CONFIG = {"distributed.scheduler.worker-saturation": 1.0}


@dataclass(frozen=True)
class Lost:
    """A task given up on (Dask only): its worker died on every try; ``error`` is Dask's reason, one line."""

    task: object
    error: str


@dataclass(frozen=True)
class Executor:
    """How tasks run: ``kind`` local or dask, ``workers`` local (or LocalCluster) processes, Dask ``scheduler`` address."""

    kind: str = LOCAL
    workers: int = 2
    scheduler: str | None = None  # dask only; None: a LocalCluster of ``workers`` processes, one thread each
    retries: int = 1  # dask only: extra tries of a task that raised, and worker deaths a task may cause

    def __post_init__(self) -> None:
        if self.kind not in (LOCAL, DASK):
            raise PatternshopError(f"executor must be {LOCAL} or {DASK}, got {self.kind!r}")
        if self.scheduler and self.kind != DASK:
            raise PatternshopError(f"scheduler={self.scheduler} needs executor={DASK}")
        if self.workers < 1 or self.retries < 0:
            raise PatternshopError(f"workers must be >= 1 and retries >= 0, got {self.workers} and {self.retries}")

    @classmethod
    def from_config(cls, cfg) -> Executor:  # noqa: ANN001 - omegaconf.DictConfig with workers, executor, scheduler
        """From a Hydra config's ``executor``, ``workers`` and ``scheduler`` (the last two optional)."""
        return cls(str(cfg.get("executor", LOCAL)), int(cfg.get("workers", 2)), cfg.get("scheduler") or None)

    def describe(self) -> str:
        """``local x2``, ``dask LocalCluster x2`` or ``dask tcp://host:8786``: for run records."""
        if self.kind == LOCAL:
            return f"local x{self.workers}"
        return f"dask {self.scheduler}" if self.scheduler else f"dask LocalCluster x{self.workers}"

    def map_unordered(self, function: Callable, tasks: Sequence, initializer: Callable | None = None,
                      initargs: tuple = (), window: int | None = None, in_process: bool = True) -> Iterator:
        """``function(task)`` for every task, yielded in order of completion (or :class:`Lost`, Dask only).

        ``function``, the tasks and ``initializer`` must be picklable (module-level). Local: at most
        ``window`` tasks pending (default twice the workers), so an interrupt leaves little half-done work;
        with one worker (or one task) in this process unless ``in_process`` is False. Dask: all tasks are
        submitted at once and the scheduler balances them.
        """
        if not tasks:
            return
        if self.kind == DASK:
            yield from self._dask_map(function, tasks, initializer, initargs)
            return
        workers = min(self.workers, len(tasks))
        if workers <= 1 and in_process:
            if initializer is not None:
                initializer(*initargs)
            yield from map(function, tasks)
        else:
            yield from _pool_map(function, tasks, max(1, workers), window or 2 * workers, initializer, initargs)

    def _dask_map(self, function: Callable, tasks: Sequence, initializer: Callable | None, initargs: tuple) -> Iterator:
        import dask
        from distributed import Client, LocalCluster, as_completed
        from distributed.scheduler import KilledWorker

        cluster = None
        try:
            if self.scheduler is None:
                with dask.config.set(SCHEDULER_CONFIG):
                    cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                           silence_logs=logging.ERROR, scheduler_kwargs={"allowed_failures": self.retries})
            client = Client(cluster if cluster is not None else self.scheduler, set_as_default=False)
        except OSError as exc:  # unreachable or refused scheduler: one line, like other user errors
            if cluster is not None:
                cluster.close()
            raise PatternshopError(f"cannot reach the Dask scheduler {self.scheduler}: {' '.join(str(exc).split())}") from exc
        futures: list = []
        try:
            futures = client.map(_Initialised(function, initializer, initargs), tasks, retries=self.retries, pure=False)
            task_of = {future.key: task for future, task in zip(futures, tasks)}
            for future in as_completed(futures, loop=client.loop):
                if future.status == "error" and isinstance(future.exception(), KilledWorker):
                    reason = " ".join(str(future.exception()).split()).split(" Inspecting worker logs")[0]  # less the advice
                    yield Lost(task_of[future.key], reason)
                else:
                    yield future.result()  # raises the task's exception after its retries
                future.release()
        finally:
            client.cancel(futures)
            client.close()
            if cluster is not None:
                cluster.close()


class _Initialised:
    """``function(task)`` after ``initializer(*initargs)`` has run once in this process (Dask workers have no initializer)."""

    _done: tuple | None = None  # (initializer, initargs) this process was last initialised with
    _lock = threading.Lock()

    def __init__(self, function: Callable, initializer: Callable | None, initargs: tuple) -> None:
        from dask.utils import funcname

        self.function, self.initializer, self.initargs = function, initializer, initargs
        self.__name__ = funcname(function)  # Dask names the tasks after it

    def __call__(self, task: object) -> object:
        if self.initializer is not None:
            with _Initialised._lock:
                if _Initialised._done != (self.initializer, self.initargs):
                    self.initializer(*self.initargs)
                    _Initialised._done = (self.initializer, self.initargs)
        return self.function(task)


def _start_worker(initializer: Callable | None, initargs: tuple) -> None:
    """Local worker start: leave Ctrl+C to the parent (it stops the pool), then the caller's initializer."""
    from tqdm import tqdm

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # tqdm's default lock is a named multiprocessing semaphore: a terminated worker would leave it to the
    # resource tracker, which complains on stderr; a worker's progress bars (disabled) need no cross-process lock
    tqdm.set_lock(threading.RLock())
    if initializer is not None:
        initializer(*initargs)


def _next_result(done: queue.SimpleQueue, processes: list) -> object:
    """The next result a pool worker put in ``done``; a dead worker (killed, out of memory) stops the run instead of
    leaving it waiting forever for a task that the pool lost."""
    while True:
        try:
            return done.get(timeout=1.0)
        except queue.Empty:
            dead = [process.exitcode for process in processes if process.exitcode is not None]
            if dead:
                raise PatternshopError(f"a worker process died (exit code {dead[0]}: killed, or out of memory?); "
                                       "rerun to resume, or use executor=dask, which retries its items") from None


def _pool_map(function: Callable, tasks: Sequence, workers: int, window: int, initializer: Callable | None,
              initargs: tuple) -> Iterator:
    """The local back end: ``workers`` spawned processes, at most ``window`` tasks pending; terminated on any exception."""
    done: queue.SimpleQueue = queue.SimpleQueue()
    others = set(multiprocessing.active_children())
    pool = multiprocessing.get_context("spawn").Pool(workers, initializer=_start_worker, initargs=(initializer, initargs))
    processes = [process for process in multiprocessing.active_children() if process not in others]  # the pool's workers
    try:
        pending = 0
        for task in itertools.chain(tasks, [None] * window):
            if task is not None:
                pool.apply_async(function, (task,), callback=done.put, error_callback=done.put)
                pending += 1
            while pending and (pending >= window or task is None):
                result = _next_result(done, processes)
                pending -= 1
                if isinstance(result, BaseException):
                    raise result
                yield result
        pool.close()
    finally:
        pool.terminate()
        pool.join()
