"""Fused numba kernels for the synthesis objective of :mod:`synthesis.edgepcf` (same maths, same results).

Every kernel is a parallel loop that only gathers (no two threads write one
element): pair counts by centre, window sums by window and their adjoint by
point (through the transposed membership lists), forces by centre and then
collected by neighbour (through the transposed pair lists). :func:`objective` must agree with
:func:`synthesis.edgepcf.objective_reference` (tests compare them).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from synthesis.edgepcf import Neighbourhoods, dead_zone

_JIT = {"parallel": True, "cache": True, "fastmath": False}


@numba.njit(**_JIT)
def _pair_counts(xy, offsets, neighbours, guide, spacing, inv_width, expected, excess, cumulative):  # pragma: no cover
    n, m = excess.shape
    for c in numba.prange(n):
        row = excess[c]
        for j in range(m):
            row[j] = -expected[c, j]
        scale = inv_width / spacing[c]
        xc, yc = xy[c, 0], xy[c, 1]
        for p in range(offsets[c], offsets[c + 1]):
            k = neighbours[p]
            dx, dy = xy[k, 0] - xc, xy[k, 1] - yc
            t = math.sqrt(dx * dx + dy * dy) * scale
            if t < m:
                j = int(t)
                f = t - j
                row[j] += guide[p] * (1.0 - f)
                if j + 1 < m:
                    row[j + 1] += guide[p] * f
        total = 0.0
        for j in range(m):
            total += row[j]
            cumulative[c, j] = total


@numba.njit(**_JIT)
def _window_sums(values, window_offsets, members, weights, out):  # pragma: no cover - jitted
    windows, m = out.shape
    for w in numba.prange(windows):
        for j in range(m):
            out[w, j] = 0.0
        for q in range(window_offsets[w], window_offsets[w + 1]):
            a = weights[q]
            c = members[q]
            for j in range(m):
                out[w, j] += a * values[c, j]


@numba.njit(**_JIT)
def _distribute(values, member_offsets, by_member, window_of_entry, weights, out):  # pragma: no cover - jitted
    n, m = out.shape
    for c in numba.prange(n):
        for j in range(m):
            out[c, j] = 0.0
        for q in range(member_offsets[c], member_offsets[c + 1]):
            e = by_member[q]
            a = weights[e]
            w = window_of_entry[e]
            for j in range(m):
                out[c, j] += a * values[w, j]


@numba.njit(**_JIT)
def _add_reverse_cumsum(target, cumulative):  # pragma: no cover - jitted
    n, m = target.shape
    for c in numba.prange(n):
        total = 0.0
        for j in range(m - 1, -1, -1):
            total += cumulative[c, j]
            target[c, j] += total


@numba.njit(**_JIT)
def _forces(xy, offsets, neighbours, guide, spacing, inv_width, back, force, grad):  # pragma: no cover - jitted
    n, m = back.shape
    for c in numba.prange(n):
        scale = inv_width / spacing[c]
        xc, yc = xy[c, 0], xy[c, 1]
        gx, gy = 0.0, 0.0
        for p in range(offsets[c], offsets[c + 1]):
            k = neighbours[p]
            dx, dy = xy[k, 0] - xc, xy[k, 1] - yc
            d = math.sqrt(dx * dx + dy * dy)
            t = d * scale
            fx, fy = 0.0, 0.0
            if t < m and d > 0.0:
                j = int(t)
                upper = back[c, j + 1] if j + 1 < m else 0.0
                slope = guide[p] * (upper - back[c, j]) * scale / d
                fx, fy = slope * dx, slope * dy
            force[p, 0], force[p, 1] = fx, fy
            gx -= fx
            gy -= fy
        grad[c, 0], grad[c, 1] = gx, gy


@numba.njit(**_JIT)
def _collect_forces(neighbour_offsets, by_neighbour, force, grad):  # pragma: no cover - jitted
    n = grad.shape[0]
    for k in numba.prange(n):
        for q in range(neighbour_offsets[k], neighbour_offsets[k + 1]):
            p = by_neighbour[q]
            grad[k, 0] += force[p, 0]
            grad[k, 1] += force[p, 1]


class FastObjective:
    """Objective and gradient for one neighbourhood, with buffers reused across iterations."""

    def __init__(self, hood: Neighbourhoods):
        self.hood = hood
        n, m = hood.expected.shape
        self.inv_width = 1.0 / float(hood.radii[1] - hood.radii[0])
        self.owners = [windows.owners for windows in hood.windows]
        self.sums = [np.empty((len(windows.offsets) - 1, m)) for windows in hood.windows]
        self.excess = np.empty((n, m))
        self.cumulative = np.empty((n, m))
        self.back = np.empty((n, m))
        self.back_cumulative = np.empty((n, m))
        self.part = np.empty((n, m))
        self.force = np.empty((len(hood.neighbours), 2))
        self.slope_x = np.ascontiguousarray(hood.expected_slope[..., 0])  # (K, m) each: faster than einsum per step
        self.slope_y = np.ascontiguousarray(hood.expected_slope[..., 1])
        self.grad = np.empty((n, 2))

    def __call__(self, xy: np.ndarray, gradient: bool = True) -> tuple[float, np.ndarray | None]:
        """Objective and gradient (n, 2) (a reused buffer: copy it to keep it) at xy (n, 2) float64."""
        hood = self.hood
        m = self.excess.shape[1]
        _pair_counts(xy, hood.offsets, hood.neighbours, hood.guide, hood.spacing, self.inv_width, hood.expected,
                     self.excess, self.cumulative)
        if len(hood.sloped):  # expected counts that move with the point (near borders and edges)
            moved = xy[hood.sloped] - hood.anchor[hood.sloped]
            shift = self.slope_x * moved[:, :1] + self.slope_y * moved[:, 1:]
            self.excess[hood.sloped] -= shift
            self.cumulative[hood.sloped] -= np.cumsum(shift, axis=1)
        loss = 0.0
        self.back.fill(0.0)
        self.back_cumulative.fill(0.0)
        for windows, owners, sums in zip(hood.windows, self.owners, self.sums):
            counts = self.cumulative if windows.scale.cumulative else self.excess
            _window_sums(counts, windows.offsets, windows.members, windows.weights, sums)
            standardised = np.divide(sums, windows.deviation, out=sums)
            penalty, slope = dead_zone(standardised, windows.scale.dead_zone)
            scale = windows.scale.weight / (len(sums) * m)
            loss += float(penalty.sum()) * scale
            if gradient:
                slope *= scale
                slope /= windows.deviation
                _distribute(slope, windows.member_offsets, windows.by_member, owners, windows.weights, self.part)
                (self.back_cumulative if windows.scale.cumulative else self.back).__iadd__(self.part)
        if len(hood.sloped):
            loss += float(np.sum(hood.variance_force * (xy[hood.sloped] - hood.anchor[hood.sloped])))
        if not gradient:
            return loss, None
        _add_reverse_cumsum(self.back, self.back_cumulative)
        _forces(xy, hood.offsets, hood.neighbours, hood.guide, hood.spacing, self.inv_width, self.back, self.force, self.grad)
        _collect_forces(hood.neighbour_offsets, hood.by_neighbour, self.force, self.grad)
        if len(hood.sloped):
            back = self.back[hood.sloped]
            self.grad[hood.sloped, 0] -= (back * self.slope_x).sum(axis=1)
            self.grad[hood.sloped, 1] -= (back * self.slope_y).sum(axis=1)
            self.grad[hood.sloped] += hood.variance_force
        return loss, self.grad


def window_sums(values: np.ndarray, offsets: np.ndarray, members: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(W, m) window sums ``sum_q weights[q] values[members[q]]`` over each window's entries ``offsets[w]:offsets[w + 1]``."""
    out = np.empty((len(offsets) - 1, values.shape[1]))
    _window_sums(np.ascontiguousarray(values, np.float64), offsets, members, weights, out)
    return out


def distribute_sums(values: np.ndarray, member_offsets: np.ndarray, by_member: np.ndarray, owners: np.ndarray,
                    weights: np.ndarray) -> np.ndarray:
    """(n, m) per-point sums ``sum weights[e] values[owners[e]]`` over each point's entries (the adjoint of :func:`window_sums`)."""
    out = np.empty((len(member_offsets) - 1, values.shape[1]))
    _distribute(np.ascontiguousarray(values, np.float64), member_offsets, by_member, owners, weights, out)
    return out
