"""Numba kernels of :mod:`synthesis.fields`: bilinear sampling of grids at points, and the Poisson denominator's polar quadrature (:meth:`synthesis.fields.MapFields.denominator_at`).

Same sampling as the numpy reference (:meth:`MapFields._quadrature_reference`):
each node's pixel's intensity and density level, bilinear latent (edges clamped), nodes outside the domain
count 0, guidance ``exp(-|dz|^2 / (2 bandwidth))``; tests compare the two.
"""

from __future__ import annotations

import math

import numba
import numpy as np

LEVEL_DEAD_ZONE = 0.16  # differences of the guide's density level within this count 0 (see synthesis.fields.DENSITY_GUIDE)


@numba.njit(cache=True)
def guide_gap(d, c):  # pragma: no cover - jitted
    """The guide's distance along coordinate c of a difference d: d itself for the latent z (c < 2), the density level's
    (c = 2) beyond :data:`LEVEL_DEAD_ZONE`."""
    return d if c < 2 else max(abs(d) - LEVEL_DEAD_ZONE, 0.0)


@numba.njit(cache=True)
def corners(height, width, x, y):  # pragma: no cover - jitted
    """Bilinear stencil at pixel-index coordinates (x, y) of a (height, width) grid, edges clamped: r0, r1, c0, c1, tx, ty."""
    x = min(max(x, 0.0), width - 1.0)
    y = min(max(y, 0.0), height - 1.0)
    c0 = min(int(x), max(width - 2, 0))
    r0 = min(int(y), max(height - 2, 0))
    return r0, min(r0 + 1, height - 1), c0, min(c0 + 1, width - 1), x - c0, y - r0


@numba.njit(parallel=True, cache=True)
def grid_samples(grid, px, py, out):  # pragma: no cover - jitted
    """Bilinear samples into out (n, C) of a (H, W, C) grid at pixel-index coordinates px, py (n,), edges clamped."""
    height, width, channels = grid.shape
    for i in numba.prange(len(px)):
        r0, r1, c0, c1, tx, ty = corners(height, width, px[i], py[i])
        for k in range(channels):
            top = grid[r0, c0, k] * (1.0 - tx) + grid[r0, c1, k] * tx
            bottom = grid[r1, c0, k] * (1.0 - tx) + grid[r1, c1, k] * tx
            out[i, k] = top * (1.0 - ty) + bottom * ty


@numba.njit(parallel=True, cache=True)
def table_samples(table, colour, px, py, out):  # pragma: no cover - jitted
    """Bilinear samples into out (n, C) of the (H, W, C) grid ``table[colour]`` (rows of a (K, C) table, indexed per
    pixel by colour (H, W)) at pixel-index coordinates px, py (n,), edges clamped: :func:`grid_samples`'s arithmetic on
    the same values, without the grid (a map's few colours stay in cache)."""
    height, width = colour.shape
    for i in numba.prange(len(px)):
        r0, r1, c0, c1, tx, ty = corners(height, width, px[i], py[i])
        k00, k01, k10, k11 = colour[r0, c0], colour[r0, c1], colour[r1, c0], colour[r1, c1]
        for k in range(table.shape[1]):
            top = table[k00, k] * (1.0 - tx) + table[k01, k] * tx
            bottom = table[k10, k] * (1.0 - tx) + table[k11, k] * tx
            out[i, k] = top * (1.0 - ty) + bottom * ty


@numba.njit(cache=True)
def _outside_arc(distance, radius):  # pragma: no cover - jitted
    """Half-angle of the arc of a circle of ``radius`` beyond a straight border ``distance`` away (0 if it does not reach)."""
    return math.acos(max(distance / radius, -1.0)) if distance < radius else 0.0  # a centre beyond it: up to a whole turn


@numba.njit(parallel=True, cache=True)
def border_shares(x, y, spacing, width, height, ring_radii):  # pragma: no cover - jitted
    """(k, R) share of each circle (radius ring_radii * spacing) around points (x, y) inside ``[0, width] x [0, height]``.

    Closed form: the arcs beyond the left, right, bottom and top borders are
    centred a quarter turn apart, so (while a circle is narrower than the
    domain) their union is their sum minus the overlaps of neighbouring pairs
    (corners).
    """
    out = np.empty((len(x), len(ring_radii)))
    quarter = 0.5 * math.pi
    for i in numba.prange(len(x)):
        for r in range(len(ring_radii)):
            radius = ring_radii[r] * spacing[i]
            left, right = _outside_arc(x[i], radius), _outside_arc(width - x[i], radius)
            bottom, top = _outside_arc(y[i], radius), _outside_arc(height - y[i], radius)
            outside = 2.0 * (left + right + bottom + top)
            for first, second in ((right, top), (top, left), (left, bottom), (bottom, right)):
                outside -= max(0.0, min(first, quarter + second) - max(-first, quarter - second))  # corner
            out[i, r] = min(max(1.0 - outside / (2.0 * math.pi), 0.0), 1.0)
    return out


@numba.njit(cache=True)
def _bilinear(plane, x, y):  # pragma: no cover - jitted
    r0, r1, c0, c1, tx, ty = corners(plane.shape[0], plane.shape[1], x, y)
    top = plane[r0, c0] * (1.0 - tx) + plane[r0, c1] * tx
    bottom = plane[r1, c0] * (1.0 - tx) + plane[r1, c1] * tx
    return top * (1.0 - ty) + bottom * ty


@numba.njit(cache=True)
def _stepped_pair(first, second, step, stepped, x, y):  # pragma: no cover - jitted
    """Samples of two (height, width) planes at pixel-index coordinates (x, y), edges clamped, from one stencil:
    bilinear, or on a pixel marked in ``step`` (uint8, same shape; tested only where ``stepped``) that pixel's own values
    (as :meth:`synthesis.fields.MapFields.snapped`)."""
    height, width = first.shape
    if stepped:
        row = min(max(int(math.floor(y + 0.5)), 0), height - 1)
        col = min(max(int(math.floor(x + 0.5)), 0), width - 1)
        if step[row, col]:
            return first[row, col], second[row, col]
    r0, r1, c0, c1, tx, ty = corners(height, width, x, y)
    a = (first[r0, c0] * (1.0 - tx) + first[r0, c1] * tx) * (1.0 - ty) + (first[r1, c0] * (1.0 - tx) + first[r1, c1] * tx) * ty
    b = (second[r0, c0] * (1.0 - tx) + second[r0, c1] * tx) * (1.0 - ty) + (second[r1, c0] * (1.0 - tx) + second[r1, c1] * tx) * ty
    return a, b


@numba.njit(parallel=True, cache=True)
def ring_means(intensity, planes, step, px0, py0, spacing_px, centre, own,
               dx, dy, node_ring, rings, guide, first, ends, stepped, bandwidth):  # pragma: no cover - jitted
    """(k, R) mean over each ring's nodes of ``lambda(y) H(y, x) [y inside] / lambda(x)`` around k points (pixel-index
    coordinates); the guide coordinates are (C, H, W) planes, (k, C) at the points; lambda and the last coordinate (the
    density level) at a node are bilinear, a ``step`` pixel's own value on it (uint8 (H, W); (0, 0): no step), the
    others bilinear (as :meth:`synthesis.fields.MapFields.guide_at`); around point i only coordinates ``first`` to
    ``ends[i]`` are read (a one-colour map's z is the same everywhere; a level that stays within its dead zone gaps 0),
    and ``step`` only where ``stepped[i]`` (a step pixel within reach)."""
    k = len(px0)
    height, width = intensity.shape
    out = np.zeros((k, rings))
    counts = np.zeros(rings)
    for q in range(len(node_ring)):
        counts[node_ring[q]] += 1.0
    for i in numba.prange(k):
        if ends[i] <= 2 and not stepped[i]:  # bilinear lambda and at most z (most points)
            for q in range(len(dx)):
                x = px0[i] + spacing_px[i] * dx[q]
                y = py0[i] + spacing_px[i] * dy[q]
                if x < -0.5 or x > width - 0.5 or y < -0.5 or y > height - 0.5:
                    continue
                weight = _bilinear(intensity, x, y) / own[i]
                if guide and first == 0:
                    da = _bilinear(planes[0], x, y) - centre[i, 0]
                    db = _bilinear(planes[1], x, y) - centre[i, 1]
                    weight *= math.exp(-(da * da + db * db) / (2.0 * bandwidth))
                out[i, node_ring[q]] += weight
            continue
        for q in range(len(dx)):
            x = px0[i] + spacing_px[i] * dx[q]
            y = py0[i] + spacing_px[i] * dy[q]
            if x < -0.5 or x > width - 0.5 or y < -0.5 or y > height - 0.5:
                continue
            lam, level = _stepped_pair(intensity, planes[2], step, stepped[i], x, y)
            weight = lam / own[i]
            if guide:
                d2 = 0.0
                for c in range(first, min(ends[i], 2)):  # the latent z: bilinear
                    d = _bilinear(planes[c], x, y) - centre[i, c]
                    d2 += d * d
                if ends[i] > 2:
                    d = guide_gap(level - centre[i, 2], 2)
                    d2 += d * d
                if d2 > 1e-20:  # exp rounds to 1.0 there anyway (a photograph's nodes, mostly: within the dead zone)
                    weight *= math.exp(-d2 / (2.0 * bandwidth))
            out[i, node_ring[q]] += weight
    for r in range(rings):
        out[:, r] /= counts[r]
    return out


@numba.njit(cache=True)
def _running_median(values, half, out):  # pragma: no cover - jitted
    width = values.shape[1]
    size = 2 * half + 1
    window = np.empty(size)  # the row's window around pixel j, sorted
    for i in range(values.shape[0]):
        for k in range(size):
            window[k] = values[i, min(max(k - half, 0), width - 1)]
        window.sort()
        out[i, 0] = window[half]
        for j in range(1, width):  # the window slides by one: one value leaves, one enters
            gone = values[i, max(j - 1 - half, 0)]
            new = values[i, min(j + half, width - 1)]
            if new != gone:
                k = 0
                while k < size - 1 and window[k] != gone:  # bounded: a NaN is never found
                    k += 1
                if new > gone:  # the values between move down one place, the new one takes the gap
                    while k + 1 < size and window[k + 1] < new:
                        window[k] = window[k + 1]
                        k += 1
                else:
                    while k > 0 and window[k - 1] > new:
                        window[k] = window[k - 1]
                        k -= 1
                window[k] = new
            out[i, j] = window[half]


def running_median(values: np.ndarray, half: int) -> np.ndarray:
    """(H, W) float64 the median of each row's ``2 half + 1`` values around each pixel of values (H, W), edges repeated:
    ``scipy.ndimage.median_filter(values, size=(1, 2 half + 1), mode="nearest")`` (tests compare them), without
    importing scipy.ndimage. The window is kept sorted as it slides (one value out, one in: a few moves a pixel, none
    where they are equal, as on a map's flat areas) instead of sorted at every pixel (the logo's fields: 7.8 -> 0.3 ms
    a pass; random values, 256^2 px, half 6: 22 -> 2 ms). Equal values are interchangeable (-0.0 and 0.0 may swap: they
    compare equal); values with NaN (never here: logarithms of a positive intensity) give other medians than scipy's."""
    values = np.ascontiguousarray(values, np.float64)
    out = np.empty_like(values)
    _running_median(values, int(half), out)
    return out


@numba.njit(cache=True)
def _tent(x, inv_cell, size, pad):  # pragma: no cover - jitted
    """Tent stencil of coordinate x on cells of 1 / inv_cell, ``pad`` of them before the origin: lower and upper cell
    (clamped to 0..size-1), upper weight."""
    u = x * inv_cell - 0.5 + pad
    k = math.floor(u)
    f = u - k
    k = int(k)
    return min(max(k, 0), size - 1), min(max(k + 1, 0), size - 1), f


@numba.njit(cache=True)
def bilinear_splat(xy, inv_cw, inv_ch, counts, pad):  # pragma: no cover - jitted
    """Add the tent (bilinear) counts of points xy (n, 2) into counts (Gh, Gw), cells 1 / inv_cw x 1 / inv_ch wide from
    ``pad`` cells before the origin (mass beyond the outer cell centres stays in the outer cells). Reference:
    :meth:`synthesis.density_term.DensityTerm.counts_reference`."""
    gh, gw = counts.shape
    for i in range(len(xy)):
        j0, j1, fu = _tent(xy[i, 0], inv_cw, gw, pad)
        i0, i1, fv = _tent(xy[i, 1], inv_ch, gh, pad)
        counts[i0, j0] += (1.0 - fv) * (1.0 - fu)
        counts[i0, j1] += (1.0 - fv) * fu
        counts[i1, j0] += fv * (1.0 - fu)
        counts[i1, j1] += fv * fu


@numba.njit(parallel=True, cache=True)
def bilinear_gradient(xy, inv_cw, inv_ch, u, out, pad):  # pragma: no cover - jitted
    """Add into out (n, 2) the gradient at points xy (n, 2) of the tent interpolant of u (Gh, Gw) (the splat's adjoint,
    :func:`bilinear_splat`'s cells, ``pad`` before the origin). Reference: :meth:`synthesis.density_term.DensityTerm.reference`."""
    gh, gw = u.shape
    for i in numba.prange(len(xy)):
        j0, j1, fu = _tent(xy[i, 0], inv_cw, gw, pad)
        i0, i1, fv = _tent(xy[i, 1], inv_ch, gh, pad)
        out[i, 0] += ((1.0 - fv) * (u[i0, j1] - u[i0, j0]) + fv * (u[i1, j1] - u[i1, j0])) * inv_cw
        out[i, 1] += ((1.0 - fu) * (u[i1, j0] - u[i0, j0]) + fu * (u[i1, j1] - u[i0, j1])) * inv_ch


@numba.njit(cache=True)
def nearest_true(mask):  # pragma: no cover - jitted
    """(H, W, 2) int32 (row, col) of the True pixel nearest (Euclidean, centre to centre) to every pixel of a (H, W) bool
    mask with at least one True: the exact lower envelope of parabolas (Felzenszwalb and Huttenlocher), by column, then
    by row. The feature transform of ``scipy.ndimage.distance_transform_edt(~mask, return_indices=True)``: the same
    distances; of equally near pixels it may pick another."""
    height, width = mask.shape
    rows = np.empty((height, width), np.int64)  # the nearest True row in the same column (-1: none in the column)
    for x in range(width):
        last = -1
        for y in range(height):
            if mask[y, x]:
                last = y
            rows[y, x] = last
        last = -1
        for y in range(height - 1, -1, -1):
            if mask[y, x]:
                last = y
            if last >= 0 and (rows[y, x] < 0 or last - y < y - rows[y, x]):
                rows[y, x] = last
    out = np.empty((height, width, 2), np.int32)
    v = np.empty(width, np.int64)  # columns whose parabolas form the envelope ...
    z = np.empty(width + 1)  # ... and where each takes over
    for y in range(height):
        k = -1
        for q in range(width):
            if rows[y, q] < 0:
                continue
            fq = float((y - rows[y, q]) ** 2 + q * q)
            s = -np.inf
            while k >= 0:
                p = v[k]
                s = (fq - float((y - rows[y, p]) ** 2 + p * p)) / (2.0 * (q - p))
                if s > z[k]:
                    break
                k -= 1
            if k < 0:
                s = -np.inf
            k += 1
            v[k] = q
            z[k] = s
        z[k + 1] = np.inf
        k = 0
        for q in range(width):
            while z[k + 1] < q:
                k += 1
            out[y, q, 0] = rows[y, v[k]]
            out[y, q, 1] = v[k]
    return out


@numba.njit(parallel=True, cache=True, fastmath=True)
def _separable_blur(values, down, across, threads, out):  # pragma: no cover - jitted
    """out (H, W) = values (H, W) correlated with ``down`` along the columns, then with ``across`` along the rows
    (odd-length weights centred on the pixel, zero beyond the edges); each of ``threads`` takes a run of rows."""
    height, width = values.shape
    reach = len(across) // 2
    for t in numba.prange(threads):
        row = np.empty(width + 2 * reach)  # one row blurred down the columns, zero-padded for the pass along it
        inner = row[reach:reach + width]
        for i in range(t * height // threads, (t + 1) * height // threads):
            row[:] = 0.0
            for k in range(len(down)):
                source = i + k - len(down) // 2
                if 0 <= source < height:
                    weight, line = down[k], values[source]  # the tap and the source row as their own names: the
                    # loop vectorises (the same sums; 318^2 cells, 19 taps: 1.14 -> 0.56 ms a blur)
                    for j in range(width):
                        inner[j] += weight * line[j]
            for j in range(width):
                total = 0.0
                for k in range(len(across)):
                    total += across[k] * row[j + k]
                out[i, j] = total


def gaussian_blur(values: np.ndarray, sigma: tuple[float, float], truncate: float, out: np.ndarray | None = None,
                  taps: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(H, W) float64 Gaussian blur of values (H, W) with standard deviations ``sigma`` (rows, columns) in pixels, zero
    beyond the edges, each axis's kernel cut at ``int(truncate sigma + 0.5)`` pixels and normalised to sum 1: what
    ``scipy.ndimage.gaussian_filter(values, sigma, mode="constant", truncate=truncate)`` gives, to rounding (tests
    compare them), without importing scipy.ndimage (0.13 s of a synthesis's start-up). ``out``: an (H, W) float64 array
    to fill (not ``values``); ``taps``: :func:`gaussian_taps` of ``sigma`` and ``truncate`` per axis, computed once by a
    caller that blurs often (the tone term: twice an iteration)."""
    out = np.empty(np.shape(values)) if out is None else out
    down, across = taps or (gaussian_taps(sigma[0], truncate), gaussian_taps(sigma[1], truncate))
    _separable_blur(np.ascontiguousarray(values, np.float64), down, across, numba.get_num_threads(), out)
    return out


def gaussian_taps(sd: float, truncate: float) -> np.ndarray:
    """(2 K + 1,) a Gaussian of standard deviation ``sd`` (pixels) at offsets -K..K, K = ``int(truncate sd + 0.5)``,
    normalised to sum 1 (``scipy.ndimage.gaussian_filter``'s kernel)."""
    x = np.arange(-int(truncate * sd + 0.5), int(truncate * sd + 0.5) + 1)
    phi = np.exp(-0.5 / (sd * sd) * x**2)
    return phi / phi.sum()


@numba.njit(parallel=True, cache=True)
def edge_pass(values, taps, tau, out):  # pragma: no cover - jitted
    """out (H, W) = values (H, W) blurred along its rows by ``taps`` (2 K + 1, symmetric), each tap's weight times the
    product of the transmittances ``tau`` (H, W - 1; between columns j and j + 1) crossed on the way, zero beyond the
    ends: a symmetric operator that stops at edges. Reference: :func:`synthesis.density_term.edge_pass_reference`."""
    height, width = values.shape
    reach = len(taps) // 2
    for i in numba.prange(height):
        right = np.ones(width)  # products of the transmittances from each cell to the one k to its right ...
        left = np.ones(width)  # ... and k to its left, over k (inner loops along the row: they vectorise)
        for j in range(width):
            out[i, j] = taps[reach] * values[i, j]
        for k in range(1, min(reach, width - 1) + 1):
            for j in range(width - k):
                right[j] *= tau[i, j + k - 1]
                out[i, j] += taps[reach + k] * right[j] * values[i, j + k]
            for j in range(k, width):
                left[j] *= tau[i, j - k]
                out[i, j] += taps[reach - k] * left[j] * values[i, j - k]
