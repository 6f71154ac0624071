"""The numba kernels' on-disk cache: say so when a first run has to compile them.

The kernels are compiled with ``cache=True``: the first run in a fresh
installation (or after a kernel's source changed, or with an empty
``NUMBA_CACHE_DIR``) compiles them, about 15 s of silence, and later runs load
them in a fraction of a second. :func:`announce_compilation` prints one line on
stderr before such a first run; :func:`load_cached_kernels_lazily` loads them without numba's typing and lowering
registries (0.1 s), which only compiling needs.
"""

from __future__ import annotations

import importlib
import sys
import types

SYNTHESIS_KERNELS = ("synthesis.cells", "synthesis.edgepcf_fast", "synthesis.fields_fast", "synthesis.neighbour_term",
                     "synthesis.step_fast", "synthesis.stratified")
_announced: set[str] = set()
_KERNEL_PACKAGE = "synthesis."  # the kernels :func:`load_cached_kernels_lazily` loads without numba's registries


def _cached(kernel: object) -> bool | None:
    """Whether numba's on-disk cache holds a compiled version of ``kernel`` whose stamp matches its source file
    (as numba checks when loading it); None where that cannot be told (not cached, or another numba's internals)."""
    try:
        cache_file = kernel._cache._cache_file  # type: ignore[attr-defined]
    except AttributeError:
        return None
    try:
        return bool(cache_file._load_index())  # {} when missing or stale
    except AttributeError:
        return None
    except Exception:  # noqa: BLE001 - an unreadable index is recompiled: not cached
        return False


def cold_modules(modules: tuple[str, ...] = SYNTHESIS_KERNELS) -> list[str]:
    """Those of ``modules`` that the next run compiles: none of their own numba kernels is in the on-disk cache.

    A whole module, not single kernels: helpers called only from other kernels are compiled into their callers
    and never cached on their own, and a changed source file makes all of its kernels stale at once.
    """
    from numba.core.dispatcher import Dispatcher

    cold = []
    for name in modules:
        module = importlib.import_module(name)
        states = [_cached(kernel) for kernel in vars(module).values()
                  if isinstance(kernel, Dispatcher) and kernel.py_func.__module__ == name]
        known = [state for state in states if state is not None]
        if known and not any(known):
            cold.append(name)
    return cold


def announce_compilation(modules: tuple[str, ...] = SYNTHESIS_KERNELS, what: str = "synthesis kernels",
                         seconds: int = 15) -> None:
    """Print one line on stderr (once per process) when kernels of ``modules`` are about to be compiled."""
    if what in _announced:
        return
    _announced.add(what)
    if cold_modules(modules):
        print(f"compiling {what} (first run only, about {seconds} s)...", file=sys.stderr, flush=True)


def skip_blas_check() -> None:
    """Load numba's array registries without importing scipy.linalg (0.1-0.3 s of every synthesis's start-up).

    When numba loads its first kernel it imports ``numba.np.arraymath``, which checks that BLAS is there by importing
    ``scipy.linalg.cython_blas``, and so the whole of scipy.linalg (its import also clones numpy's array API and loads
    numpy.f2py). None of the synthesis kernels calls BLAS; this imports that module first with a placeholder standing
    in for ``scipy.linalg.cython_blas``, removed at once. A kernel that does use ``np.dot`` or ``np.linalg`` still
    compiles and runs: numba then imports the real module (the placeholder is gone). Nothing is done where numba's
    registries or scipy.linalg are already loaded.
    """
    name = "scipy.linalg.cython_blas"
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules:
        return
    placeholder = types.ModuleType(name)
    sys.modules[name] = placeholder
    try:
        importlib.import_module("numba.np.arraymath")
    finally:
        if sys.modules.get(name) is placeholder:
            del sys.modules[name]


def load_cached_kernels_lazily() -> None:
    """Load this package's cached kernels without numba's typing and lowering registries (about 0.1 s of start-up).

    Before it loads a kernel from its on-disk cache, numba refreshes its target context: it imports and installs every
    typing and lowering registry (numba.np.arraymath, the typed containers, random, linalg: some 2,000 registrations),
    which only compiling needs; machine code loaded from the cache needs numba's runtime (NRT: the symbols its arrays
    call). This replaces ``numba.core.caching.Cache.load_overload`` with one that initialises only the runtime for the
    kernels of the ``synthesis`` package and does numba's own for every other function. A cache miss (a first run, an
    edited kernel) calls :func:`skip_blas_check` and returns nothing: numba then compiles, and compiling refreshes the
    registries itself (``numba.core.compiler``), so any kernel still compiles and runs afterwards. One registry module
    also registers symbols at its import: ``numba.cpython.hashing``'s hash secret, for hashing strings, which no
    synthesis kernel does (one that did would fail to load from the cache). Nothing is done where numba's internals
    differ from those this was written against (numba 0.6x: ``Cache._load_overload``). The same points as numba's own
    loading (``tests/test_startup.py::test_cached_kernels_load_without_numba_registries_and_give_the_same_points``).
    """
    try:
        from numba.core import caching
        from numba.core.runtime import rtsys
    except ImportError:
        return
    original = getattr(caching.Cache, "load_overload", None)
    if getattr(original, "lazy", False) or not all(hasattr(caching.Cache, name) for name in
                                                    ("_load_overload", "_guard_against_spurious_io_errors")):
        return

    def load_overload(self, sig, target_context):  # noqa: ANN001, ANN202 - numba's own signature
        module = getattr(getattr(self, "_py_func", None), "__module__", None) or ""
        if not module.startswith(_KERNEL_PACKAGE):
            return original(self, sig, target_context)
        rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():  # as numba's own (Windows: another process's write)
            loaded = self._load_overload(sig, target_context)
        if loaded is None:
            skip_blas_check()  # numba compiles next: its registries without scipy.linalg
        return loaded

    load_overload.lazy = True
    caching.Cache.load_overload = load_overload
