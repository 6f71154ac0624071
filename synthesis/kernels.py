"""The numba kernels' on-disk cache: say so when a first run has to compile them.

The kernels are compiled with ``cache=True``: the first run in a fresh
installation (or after a kernel's source changed, or with an empty
``NUMBA_CACHE_DIR``) compiles them, about 15 s of silence, and later runs load
them in a fraction of a second. :func:`announce_compilation` prints one line on
stderr before such a first run.
"""

from __future__ import annotations

import importlib
import sys
import types

SYNTHESIS_KERNELS = ("synthesis.cells", "synthesis.edgepcf_fast", "synthesis.fields_fast", "synthesis.neighbour_term",
                     "synthesis.step_fast", "synthesis.stratified")
_announced: set[str] = set()


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
