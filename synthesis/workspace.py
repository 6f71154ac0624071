"""Named scratch arrays reused from one neighbourhood refresh to the next.

A fresh large array costs a page fault per 4 KiB page when first written:
about 1.4 ms per MB on the 2-core machine (a virtual machine), more than the
kernels that fill the arrays (100k points: 83 MB of per-point counts took
130 ms to allocate and 11 ms to compute). A :class:`Workspace` hands the same
memory out again, so a synthesis touches fresh pages only in its first
refresh.
"""

from __future__ import annotations

import math

import numpy as np

GROWTH = 1.25  # a buffer that must grow gets this much headroom (pair counts vary a little between refreshes)


class Workspace:
    """Buffers by name; a second request for a name reuses (and overwrites) the memory the first one got."""

    def __init__(self) -> None:
        self._buffers: dict[str, np.ndarray] = {}
        self._asked: dict[str, int] = {}  # elements last asked for, by name

    def empty(self, name: str, shape: int | tuple[int, ...], dtype: type | np.dtype = np.float64) -> np.ndarray:
        """An uninitialised C-contiguous array of ``shape`` and ``dtype`` backed by buffer ``name``."""
        shape = (int(shape),) if np.isscalar(shape) else tuple(int(s) for s in shape)
        size = math.prod(shape)
        buffer = self._buffers.get(name)
        if buffer is None or buffer.dtype != np.dtype(dtype) or buffer.size < size:
            buffer = np.empty(size if buffer is None else int(size * GROWTH), dtype)
            self._buffers[name] = buffer
        self._asked[name] = size
        return buffer[:size].reshape(shape)

    def asked(self, name: str) -> int:
        """Elements the last request for buffer ``name`` asked for (0 before the first): ask again for fewer to record
        what was used of a larger request (the contents stay)."""
        return self._asked.get(name, 0)


def scratch(workspace: Workspace | None) -> Workspace:
    """``workspace``, or a throwaway one (fresh arrays) when None."""
    return workspace if workspace is not None else Workspace()
