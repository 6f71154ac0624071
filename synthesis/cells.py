"""Radius queries on a uniform cell grid (numba): every point within a per-centre reach, as compact lists.

The points are binned into square cells (a counting sort, O(n)); a query
scans the cells its disc overlaps and keeps the points within reach, in two
parallel passes (count, then fill), so memory follows the actual pair count
and nothing beyond reach is ever stored. Periodic domains use minimum-image
offsets. :func:`synthesis.pcf.neighbour_lists` (a cKDTree) is the plain
reference the tests compare against.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from synthesis.workspace import Workspace, scratch

MAX_CELLS_PER_POINT = 4.0  # the grid never has more cells than this many per point (tiny reaches)
REUSED_ROOM = 1.2  # a query writes its lists in one pass into this many times the room the last one of its name took


@numba.njit(cache=True)
def _bin(points, cell, nx, ny):  # pragma: no cover - jitted
    n = len(points)
    cell_of = np.empty(n, np.int64)
    start = np.zeros(nx * ny + 1, np.int64)
    for i in range(n):
        cx = min(max(int(points[i, 0] / cell[0]), 0), nx - 1)
        cy = min(max(int(points[i, 1] / cell[1]), 0), ny - 1)
        cell_of[i] = cy * nx + cx
        start[cell_of[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    order = np.empty(n, np.int32)
    fill = start[:-1].copy()
    for i in range(n):
        order[fill[cell_of[i]]] = i
        fill[cell_of[i]] += 1
    return start, order


@numba.njit(parallel=True, cache=True)
def _scan(sorted_xy, order, start, cell, nx, ny, box, periodic, centres, reach, exclude, counts, slabs, index,
          distance):  # pragma: no cover - jitted
    """Each centre's points within reach: counted into counts (C,) and written to index (and distance, unless empty),
    run t of the len(slabs) - 1 equal runs of centres from slabs[t] on, as far as they fit before slabs[t + 1]."""
    runs = len(slabs) - 1
    for t in numba.prange(runs):
        found = slabs[t]
        for q in range(t * len(centres) // runs, (t + 1) * len(centres) // runs):
            x, y, r = centres[q, 0], centres[q, 1], reach[q]
            r2 = r * r
            lo_x, hi_x = int(math.floor((x - r) / cell[0])), int(math.floor((x + r) / cell[0]))
            lo_y, hi_y = int(math.floor((y - r) / cell[1])), int(math.floor((y + r) / cell[1]))
            if periodic:
                if hi_x - lo_x + 1 > nx:
                    lo_x, hi_x = 0, nx - 1
                if hi_y - lo_y + 1 > ny:
                    lo_y, hi_y = 0, ny - 1
            else:
                lo_x, hi_x = max(lo_x, 0), min(hi_x, nx - 1)
                lo_y, hi_y = max(lo_y, 0), min(hi_y, ny - 1)
            before = found
            for iy in range(lo_y, hi_y + 1):
                cy = iy % ny if periodic else iy
                for ix in range(lo_x, hi_x + 1):
                    c = cy * nx + (ix % nx if periodic else ix)
                    for p in range(start[c], start[c + 1]):
                        dx, dy = sorted_xy[p, 0] - x, sorted_xy[p, 1] - y
                        if periodic:
                            dx -= box[0] * round(dx / box[0])
                            dy -= box[1] * round(dy / box[1])
                        d2 = dx * dx + dy * dy
                        if d2 <= r2 and order[p] != exclude[q]:
                            if found < slabs[t + 1]:
                                index[found] = order[p]
                                if len(distance):
                                    distance[found] = math.sqrt(d2)
                            found += 1
            counts[q] = found - before


class CellGrid:
    """Points (n, 2) in ``[0, w] x [0, h]`` binned into cells of side about ``cell`` for radius queries.

    ``periodic``: the domain is a torus (minimum-image distances: a point counts
    once, as with ``cKDTree(boxsize=...)``, even for reaches beyond half the side).
    """

    def __init__(self, points: np.ndarray, domain: tuple[float, float], cell: float, periodic: bool = False):
        points = np.ascontiguousarray(points, np.float64)
        self.domain = (float(domain[0]), float(domain[1]))
        self.periodic = periodic
        w, h = self.domain
        side = max(float(cell), math.sqrt(w * h / (MAX_CELLS_PER_POINT * max(len(points), 1))), 1e-12)
        # periodic: whole cells around the torus (cells a little larger than asked, never smaller)
        rounding = math.floor if periodic else math.ceil
        self.nx, self.ny = max(1, rounding(w / side)), max(1, rounding(h / side))
        self.cell = np.array([w / self.nx, h / self.ny]) if periodic else np.array([side, side])
        self.start, self.order = _bin(points, self.cell, self.nx, self.ny)
        self.sorted_xy = points[self.order]

    def query(self, centres: np.ndarray, reach: np.ndarray | float, exclude: np.ndarray | None = None,
              distances: bool = True, workspace: Workspace | None = None, name: str = "query",
              distance_name: str = "query.distance") -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Points within ``reach`` (scalar or (C,), inclusive) of each centre (C, 2), as compact lists.

        Returns offsets (C + 1,) int64 (centre c's entries are ``offsets[c]:offsets[c + 1]``),
        indices (E,) int32 and distances (E,) float64 (None unless ``distances``).
        ``exclude`` (C,): a point index each centre leaves out (itself), or -1.
        The arrays come from ``workspace`` buffers ``name.*`` when given (the distances from buffer
        ``distance_name``, one shared by all queries: overwritten by the next query).
        """
        workspace = scratch(workspace)
        centres = np.ascontiguousarray(centres, np.float64).reshape(-1, 2)
        count = len(centres)
        reach = np.ascontiguousarray(np.broadcast_to(np.asarray(reach, np.float64), (count,)))
        exclude = np.full(count, -1, np.int32) if exclude is None else np.ascontiguousarray(exclude, np.int32)
        box = np.asarray(self.domain, np.float64)
        offsets = workspace.empty(f"{name}.offsets", count + 1, np.int64)
        offsets[0] = 0
        runs = max(1, min(numba.get_num_threads(), count))
        edges = np.arange(runs + 1) * count // runs  # the kernel's runs of centres
        args = (self.sorted_xy, self.order, self.start, self.cell, self.nx, self.ny, box, self.periodic, centres, reach,
                exclude, offsets[1:])
        # one pass into the room the last query of this name needed (and a fifth more) where there was one; otherwise,
        # or where a run's points did not fit, a counting pass first (the scan is most of a neighbour refresh)
        room = int(REUSED_ROOM * workspace.asked(f"{name}.index"))
        if room:
            index = workspace.empty(f"{name}.index", room, np.int32)
            distance = workspace.empty(distance_name, room) if distances else np.empty(0)
            slabs = np.arange(runs + 1) * room // runs
            _scan(*args, slabs, index, distance)
            totals = np.add.reduceat(offsets[1:], edges[:-1]) if count else np.zeros(runs, np.int64)
            if np.all(totals <= np.diff(slabs)):
                np.cumsum(offsets, out=offsets)
                for t in range(1, runs):  # runs' lists side by side (in place: each moves down, or stays)
                    index[offsets[edges[t]]:offsets[edges[t + 1]]] = index[slabs[t]:slabs[t] + totals[t]]
                    if distances:
                        distance[offsets[edges[t]]:offsets[edges[t + 1]]] = distance[slabs[t]:slabs[t] + totals[t]]
                index = workspace.empty(f"{name}.index", offsets[-1], np.int32)  # the room used (for the next query)
                return offsets, index, distance[:offsets[-1]] if distances else None
        _scan(*args, np.zeros(runs + 1, np.int64), np.empty(0, np.int32), np.empty(0))  # count only
        np.cumsum(offsets, out=offsets)
        index = workspace.empty(f"{name}.index", offsets[-1], np.int32)
        distance = workspace.empty(distance_name, offsets[-1]) if distances else np.empty(0)
        _scan(*args, offsets[edges], index, distance)  # the counts again, over the cumulated ones
        np.cumsum(offsets, out=offsets)
        return offsets, index, distance if distances else None
