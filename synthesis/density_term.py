"""The synthesiser's tone term: the points' density, blurred at the scale of a spacing, against the map's.

The PCF objective of :mod:`synthesis.edgepcf` sees only pair counts relative to the local
density; nothing in it holds the density itself, so the points' tone at the scale of a
few dots was whatever the start left after the PCF moves (camera, 20k points: 35.9 dB of
density PSNR at a blur of 2 spacings at the start, 31.6 dB at the end). This term makes
it part of the objective. On a grid of cells a third of the blur wide (:data:`BLUR_CELLS`), with ``c`` the points' tent (bilinear) counts per cell, ``t`` the map's ink per cell
scaled to n points, ``G`` a Gaussian blur of ``scale`` mean spacings ``s = sqrt(A / n)`` (zero outside the
domain) and ``R`` the target's regularity per cell (1 for a hard core, 0 for Poisson or
clustered targets, whose density varies on this scale by design;
:func:`synthesis.edgepcf.regularity`):

    L = weight * sum_cells (G (R (c - t)))^2 / (Gh Gw v),    v = mean(t) / (4 pi sx sy)

``v`` is the variance of a blurred Poisson count at the mean density (``sx, sy``: the blur
in cells), so a Poisson pattern on a regular map scores about ``weight``.

**Border.** The grid has one more cell (:data:`PAD`) beyond each side of the domain, so every point has its full tent:
with the tents clamped to the outer cells, a point within half a cell of the border counted wholly at the outer cell's
centre and felt no force across the border there; points entered that band when the outer cells lacked ink and never
left when they had too much (the tone term alone on a true blue sample, 4,096 points, 150 iterations: 1.37 of the
expected density within 0.25 r_max of the border, 0.63 at 0.5-0.75; step's whole run, 3 seeds: 1.89 / 0.84 / 0.47 in
the first 0.25 r_max strips, 1.04 / 1.27 / 0.90 with the pad). ``t`` is accordingly the
map's ink per cell filtered by the tent, ``[1/8, 3/4, 1/8]`` per axis (the counts a pattern of the map's density is
expected to splat; padding cells get the ink of their inner neighbour's outer half); the pad cells' regularity is
their neighbour's. Its gradient is
the bilinear gradient at each point of ``u = 2 weight / (cells v) R G G R (c - t)``
(``G`` is symmetric, zero padding included).

**Edges.** ``G`` crosses the map's edges: on scikit-image's astronaut a dark strip two spacings wide beside a
paper-white panel held one column of points where it needed two, and the panel the rest, which the blur took for the
same ink. Where the map has edges, a share :data:`EDGE_SHARE` of the loss compares ``r = R (c - t)`` through an
edge-stopping blur ``B`` instead (:func:`edge_blur`): along the rows, then the columns, each tap of ``G`` times the
transmittances ``tau`` of the neighbouring cells it crosses (:func:`transmittances`: ``exp(-(log((i_a + f) / (i_b +
f)) / log 3)^2 - ((R_a - R_b) / 0.5)^2)``, ``i`` the cells' mean ink, ``f`` = :data:`INK_FLOOR`), each cell's square
divided by ``rho``, its blurred Poisson variance under ``B`` over that under ``G`` (``(B o B) 1 / (G o G) 1``, squared
taps and transmittances), so a cell that edges cut off weighs as much as its own noise:

    L = weight * sum_cells [(1 - e) (G r)^2 + e (B r)^2 / rho] / (Gh Gw v),
    u = 2 weight / (cells v) R [(1 - e) G G r + e B' (B r / rho)]     (B' the transpose: the columns first)

The plain share keeps moving ink between regions that edges part (``B`` alone, e = 1, moves it across an edge only
through the points at the edge: astronaut, 5,000 points, seed 0, density PSNR at 4 spacings 51.7 -> 39.7 dB, the
flag's stripes short of points). A map without an edge (every ``tau`` 1: a constant map) takes ``G`` alone, the same
loss bit for bit. :class:`DensityTerm` computes both, with numba kernels for the splat, the gather and ``B``'s passes
(:mod:`synthesis.fields_fast`) and :meth:`DensityTerm.reference`, plain numpy, that the tests compare them with.

**Correlation edges.** ``R (c - t)`` counted every point in a regular cell, so the points of a clustered or Poisson
target within a cell of a regular one (a red | blue edge) counted against the blue side's ink and were pushed by its
residual: red stayed off the edge (0.48 of the expected density in the first 0.5 r_max, 1.56 inside), white 0.70.
Where the cells' regularity varies, each point now counts with its own share ``s_i``, the regularity of the field pixel under
it, and the target is the ink times that pixel's regularity, integrated against each cell's tent
(:func:`_tent_means`, exact for ink uniform within each pixel): ``r = c_s - t_s``, no ``R``, and the gradient
``s_i`` times the interpolant's. A point on a clustered or Poisson pixel feels nothing; a regular point feels the
residual of regular points only. The shares are held for the run (:meth:`DensityTerm.hold_shares`, from the start):
shares read where the points are at each call let a regular point that crossed the edge drop out of the count, and the
term then pulled the next one after it (blue | white: blue's side 0.54-0.67 within 1 r_max); a held point that
crossed still counts, where the target holds no regular ink, so none follows it. Shares from the bilinear regularity instead
of the pixel's, with the gradient of the share itself: the edge's blend pushed red out of it (0.14). Maps of one
regularity (constant maps, photographs) keep ``R (c - t)``, bit for bit. Measured: docs/synthesis.md, "Border and
edge strips".

Held shares make the regular count a constant of the run: no move changes ``sum_i s_i``, and a region's count changes
only through the points at its edges, so what the start's draw left there (a mixed target's points are partly
independent: `make demo`'s edited map, 6,847 points, step background, shares' total 1.0135 of the target at seed 2,
0.98 at seed 0) the term could not remove. Its blurs, zero beyond the grid, made the border the cheapest place for
it, where part of a residual's blur falls outside: the term put it there (seed 2: the outer two cells of each side
held +51 of the +23 total, the plain path's +4), an excess as a row of points on the border, a deficit as an empty
band (per side, the points within 0.25 spacings over the inner strips', worst side, median of seeds 0-5: 5.59; the
emptiest strip of the first spacing 0.00). So split counts take both blurs mirrored at the grid's edges (the cells
repeated mirrored a blur's reach beyond them, :func:`_mirror`: a uniform residual costs as much at the border as
inside and pushes nothing) and a target scaled to the held shares' total (:meth:`DensityTerm.hold_shares`): 5.59 ->
2.94, emptiest 0.00 -> 0.27 (the plain path 1.41 / 0.21; the outer cells +5 of a total 0); bench_fidelity's strips,
3 seeds, 22 -> 24 of 24. What is left is the points' own excess in the background (+1 to +1.4 % at the end, +2.2 % away
from the logo; the plain path +0.1 %), which the shares keep and the PCF term presses against the border.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse

from synthesis.fields import MapFields, _area_matrix
from synthesis.fields_fast import edge_pass, gaussian_blur, gaussian_taps
from synthesis.labmap import LabMap, pixels_of

BLUR_CELLS = 3.0  # the blur's standard deviation in grid cells (cells of ``scale / 3`` mean spacings: a tent splat
# blurred by 3 cells has no aliasing left to speak of, and coarser cells cost less: 1M points, 1000^2 cells)
MAX_CELLS = 2048  # per side
TRUNCATE = 3.0  # the blur's reach, in its standard deviations
PAD = 1  # cells beyond each side of the domain (see the module docstring, "Border")
TENT = np.array([0.125, 0.75, 0.125])  # a cell's share of its tent's mass per axis: its own and its neighbours'
INK_FLOOR = 0.05  # density added to two neighbouring cells' mean ink before their log ratio (see "Edges")
INK_STEP = math.log(3.0)  # the log ink ratio of two neighbouring cells that passes exp(-1) of the blur across them
REGULARITY_STEP = 0.5  # likewise a step of the target's regularity
EDGE_SHARE = 0.5  # the edge-stopping blur's share of the loss where the map has edges (the plain blur's: the rest)


class DensityTerm:
    """The tone term of one map for n points (see the module docstring).

    Attributes:
        shape: (Gh + 2 PAD, Gw + 2 PAD) cells, :data:`PAD` beyond each side of the domain's Gh x Gw; ``cell``: (cw, ch)
            their size in map units; ``cells``: Gh Gw.
        target: the map's ink per cell filtered by the tent (:data:`TENT`), summing to n; where the regularity varies,
            the tent counts of the ink times its pixels' regularity (the regular share of n; "Correlation edges").
        mask: the target's regularity per cell, in [0, 1].
        regular_px: (Hf, Wf) the regularity of each field pixel (``side_px`` per map unit) where it varies, else None;
            ``shares``: (n,) the points' regular shares held by :meth:`hold_shares`, or None.
        sigma: (sy, sx) the blur in cells.
        weight: the term's weight; ``variance``: v.
    """

    def __init__(self, lab_map: LabMap, fields: MapFields, weight: float, scale: float):
        from synthesis.edgepcf import regularity, regularity_at

        w, h = fields.domain
        n = fields.n
        spacing = math.sqrt(w * h / n)
        per_unit = BLUR_CELLS / (scale * spacing)
        gw = int(min(MAX_CELLS, max(1, round(w * per_unit))))
        gh = int(min(MAX_CELLS, max(1, round(h * per_unit))))
        self.shape, self.cell = (gh, gw), (w / gw, h / gh)
        density = lab_map.density().astype(np.float64)
        ink = _area_matrix(density.shape[0], gh) @ density @ _area_matrix(density.shape[1], gw).T
        self.target = n * ink / max(float(ink.sum()), 1e-300)
        ys, xs = (np.arange(gh) + 0.5) * self.cell[1], (np.arange(gw) + 0.5) * self.cell[0]
        centres = np.stack(np.meshgrid(xs, ys, indexing="xy"), axis=-1).reshape(-1, 2)
        self.mask = regularity_at(fields, centres).reshape(gh, gw)
        self.sigma = (scale * spacing / self.cell[1], scale * spacing / self.cell[0])
        self.weight = float(weight)
        self.variance = max(float(self.target.mean()), 1e-12) / (4.0 * math.pi * self.sigma[0] * self.sigma[1])
        self.cells = gh * gw
        self.target = _tent_filter(np.pad(self.target, PAD))
        self.mask = np.pad(self.mask, PAD, mode="edge")
        self.shape = self.target.shape
        self.taps = (gaussian_taps(self.sigma[0], TRUNCATE), gaussian_taps(self.sigma[1], TRUNCATE))
        self.tau = transmittances(np.pad(ink, PAD, mode="edge"), self.mask)
        self.noise = None
        if self.tau is not None:  # each cell's Poisson variance of its blurred count over the plain blur's
            ones, squared = np.ones(self.shape), tuple(t * t for t in self.taps)
            self.noise = (edge_blur(ones, squared, tuple(t * t for t in self.tau))
                          / edge_blur(ones, squared, tuple(np.ones_like(t) for t in self.tau)))
        self.active = self.weight > 0 and bool(self.mask.max() > 0)
        self.regular_px, self.side_px, self.shares, self.mirror, self.regular_target = None, fields.side_px, None, None, None
        if self.mask.max() > self.mask.min():  # a correlation edge: counts split by regularity (see "Correlation edges")
            regular = self.regular_px = regularity(fields.target_table, fields.radii)[fields.colour].astype(np.float64)  # (Hf, Wf)
            (hm, wm), side = density.shape, fields.side_px  # each map pixel takes the field pixel under its centre
            rows = np.minimum(((np.arange(hm) + 0.5) * (h / hm) * side).astype(np.int64), regular.shape[0] - 1)
            cols = np.minimum(((np.arange(wm) + 0.5) * (w / wm) * side).astype(np.int64), regular.shape[1] - 1)
            regular_ink = density * regular[rows[:, None], cols[None, :]]
            self.target = (n / max(float(density.sum()), 1e-300)) * (_tent_means(hm, gh) @ regular_ink @ _tent_means(wm, gw).T)
            self.regular_target = self.target  # the target before hold_shares scales it to the shares' total
            # the blurs mirrored at the grid's edges ("Correlation edges", "Border"): the cells mirrored a blur's reach
            mirrors = [_mirror(size, len(taps) // 2) for size, taps in zip(self.shape, self.taps)]
            self.mirror = tuple(matrix for matrix, _ in mirrors)
            self.tau = _mirrored_tau(self.tau, *(index for _, index in mirrors))
            self.noise = None
            if self.tau is not None:
                ones, squared = np.ones((len(mirrors[0][1]), len(mirrors[1][1]))), tuple(t * t for t in self.taps)
                self.noise = self._crop(edge_blur(ones, squared, tuple(t * t for t in self.tau))
                                        / edge_blur(ones, squared, tuple(np.ones_like(t) for t in self.tau)))

    def _blur(self, values: np.ndarray) -> np.ndarray:
        return gaussian_blur(values, self.sigma, TRUNCATE, taps=self.taps)  # scipy.ndimage.gaussian_filter's, mode "constant"

    def _expand(self, values: np.ndarray) -> np.ndarray:
        """``values`` (Gh, Gw) on the grid the blurs run on: repeated mirrored a blur's reach beyond the edges for split
        counts (``My v Mx'``, :func:`_mirror`), else as they are."""
        if self.mirror is None:
            return values
        my, mx = self.mirror
        return my @ (mx @ values.T).T

    def _crop(self, values: np.ndarray) -> np.ndarray:
        """The grid's own cells (Gh, Gw) of ``values`` on the blurs' grid (:meth:`_expand`)."""
        if self.mirror is None:
            return values
        (ky, kx), (gh, gw) = (len(t) // 2 for t in self.taps), self.target.shape
        return values[ky : ky + gh, kx : kx + gw]

    def _embed(self, values: np.ndarray) -> np.ndarray:
        """The transpose of :meth:`_crop`: the grid's cells (Gh, Gw) on the blurs' grid, zero beyond."""
        if self.mirror is None:
            return values
        out = np.zeros((self.mirror[0].shape[0], self.mirror[1].shape[0]))
        self._crop(out)[...] = values
        return out

    def _fold(self, values: np.ndarray) -> np.ndarray:
        """The transpose of :meth:`_expand`: each mirrored cell's value added back onto the cell it repeats."""
        if self.mirror is None:
            return values
        my, mx = self.mirror
        return my.T @ (mx.T @ values.T).T

    def _adjoint(self, counts: np.ndarray, fast: bool = True) -> tuple[float, np.ndarray]:
        """Loss and ``u`` (Gh, Gw), dL/dcounts, from the points' counts per cell (``fast``: numba's edge blur). Split
        counts blur a residual mirrored at the grid's edges and score the grid's own cells (:meth:`_expand`)."""
        gate = self.mask if self.regular_px is None else 1.0  # split counts carry their regular shares already
        residual = self._expand(gate * (counts - self.target))
        blurred = self._crop(self._blur(residual))
        size = self.cells
        if self.tau is None:
            loss = self.weight * float(np.vdot(blurred, blurred)) / (size * self.variance)
            return loss, (2.0 * self.weight / (size * self.variance)) * gate * self._fold(self._blur(self._embed(blurred)))
        edged = self._crop(edge_blur(residual, self.taps, self.tau, fast))
        scaled = edged / self.noise
        plain = 1.0 - EDGE_SHARE
        loss = self.weight * (plain * float(np.vdot(blurred, blurred)) + EDGE_SHARE * float(np.vdot(edged, scaled)))
        u = (plain * self._blur(self._embed(blurred))
             + EDGE_SHARE * edge_blur(self._embed(scaled), self.taps, self.tau, fast, adjoint=True))
        return loss / (size * self.variance), (2.0 * self.weight / (size * self.variance)) * gate * self._fold(u)

    def __call__(self, xy: np.ndarray, gradient: np.ndarray | None = None) -> float:
        """Loss at xy (n, 2); adds its gradient into ``gradient`` (n, 2) when given (numba kernels)."""
        from synthesis.fields_fast import bilinear_gradient, bilinear_splat

        if self.regular_px is not None:  # split counts: a weighted splat (numpy), the numba gradient times the shares
            shares = self.shares_of(xy)
            loss, u = self._adjoint(self.counts_reference(xy, shares))
            if gradient is not None:
                unweighted = np.zeros_like(gradient)
                bilinear_gradient(xy, 1.0 / self.cell[0], 1.0 / self.cell[1], u, unweighted, PAD)
                gradient += shares[:, None] * unweighted
            return loss
        counts = np.zeros(self.shape)
        bilinear_splat(xy, 1.0 / self.cell[0], 1.0 / self.cell[1], counts, PAD)
        loss, u = self._adjoint(counts)
        if gradient is not None:
            bilinear_gradient(xy, 1.0 / self.cell[0], 1.0 / self.cell[1], u, gradient, PAD)
        return loss

    def hold_shares(self, xy: np.ndarray) -> None:
        """Fix each point's regular share for the calls that follow: the regularity of the field pixel under xy (n, 2),
        the points' order kept (see the module docstring, "Correlation edges"); nothing where the regularity is even."""
        self.shares = None
        if self.regular_px is not None:
            self.shares = self.shares_of(xy)  # and the target scaled to their total, which no move changes
            self.target = self.regular_target * (float(self.shares.sum()) / max(float(self.regular_target.sum()), 1e-300))

    def shares_of(self, xy: np.ndarray) -> np.ndarray:
        """(n,) the points' regular shares in [0, 1]: those held (:meth:`hold_shares`), else their field pixels'."""
        if self.shares is not None and len(self.shares) == len(xy):
            return self.shares
        return self.regular_px[pixels_of(np.asarray(xy), self.regular_px.shape, self.side_px)]

    def _corners(self, xy: np.ndarray):
        gh, gw = self.shape
        u = np.asarray(xy)[:, 0] / self.cell[0] - 0.5 + PAD
        v = np.asarray(xy)[:, 1] / self.cell[1] - 0.5 + PAD
        j0, i0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        fu, fv = u - j0, v - i0
        return (np.clip(i0, 0, gh - 1), np.clip(i0 + 1, 0, gh - 1), np.clip(j0, 0, gw - 1), np.clip(j0 + 1, 0, gw - 1),
                fu, fv)

    def counts_reference(self, xy: np.ndarray, shares: np.ndarray | None = None) -> np.ndarray:
        """(Gh, Gw) tent counts of the points xy (n, 2) per cell, each weighted by its share (n,) when given (mass beyond
        the outer centres stays in the outer cells)."""
        gh, gw = self.shape
        i0, i1, j0, j1, fu, fv = self._corners(xy)
        counts = np.zeros(gh * gw)
        for i, wi in ((i0, 1 - fv), (i1, fv)):
            for j, wj in ((j0, 1 - fu), (j1, fu)):
                weights = wi * wj if shares is None else shares * wi * wj
                counts += np.bincount(i * gw + j, weights, minlength=gh * gw)
        return counts.reshape(gh, gw)

    def reference(self, xy: np.ndarray) -> tuple[float, np.ndarray]:
        """Loss and gradient (n, 2) at xy (n, 2), plain numpy (the reference of :meth:`__call__`)."""
        shares = None if self.regular_px is None else self.shares_of(xy)
        loss, u = self._adjoint(self.counts_reference(xy, shares), fast=False)
        i0, i1, j0, j1, fu, fv = self._corners(xy)
        gx = ((1 - fv) * (u[i0, j1] - u[i0, j0]) + fv * (u[i1, j1] - u[i1, j0])) / self.cell[0]
        gy = ((1 - fu) * (u[i1, j0] - u[i0, j0]) + fu * (u[i1, j1] - u[i0, j1])) / self.cell[1]
        gradient = np.stack([gx, gy], axis=1)
        return loss, gradient if shares is None else shares[:, None] * gradient


def transmittances(ink: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """How much of the blur passes between neighbouring cells of mean ink ``ink`` (H, W, in [0, 1]) and regularity
    ``mask`` (H, W): ``exp(-(log ink ratio / INK_STEP)^2 - (regularity step / REGULARITY_STEP)^2)``, the ink floored by
    :data:`INK_FLOOR`. Returns (across (H, W - 1), between columns j and j + 1; down, transposed (W, H - 1), between
    rows), or None where every one is 1 (no edge: the plain blur)."""
    log_ink, steps = np.log(ink + INK_FLOOR) / INK_STEP, mask / REGULARITY_STEP
    across, down = (np.exp(-(np.diff(log_ink, axis=a) ** 2 + np.diff(steps, axis=a) ** 2)) for a in (1, 0))
    if across.min(initial=1.0) == 1.0 and down.min(initial=1.0) == 1.0:
        return None
    return across, np.ascontiguousarray(down.T)


def edge_blur(values: np.ndarray, taps: tuple[np.ndarray, np.ndarray], tau: tuple[np.ndarray, np.ndarray],
              fast: bool = True, adjoint: bool = False) -> np.ndarray:
    """(H, W) ``values`` blurred along the rows by ``taps[1]`` through ``tau[0]`` (H, W - 1), then along the columns by
    ``taps[0]`` through ``tau[1]`` (W, H - 1) (:func:`transmittances`); ``adjoint``: the columns first, its transpose
    (each pass is symmetric). ``fast``: numba's :func:`synthesis.fields_fast.edge_pass`, else
    :func:`edge_pass_reference`."""
    def run(v: np.ndarray, weights: np.ndarray, through: np.ndarray) -> np.ndarray:
        if not fast:
            return edge_pass_reference(v, weights, through)
        out = np.empty(v.shape)
        edge_pass(np.ascontiguousarray(v), weights, through, out)
        return out

    def rows(v: np.ndarray) -> np.ndarray:
        return run(v, taps[1], tau[0])

    def columns(v: np.ndarray) -> np.ndarray:
        return run(v.T, taps[0], tau[1]).T

    return rows(columns(values)) if adjoint else columns(rows(values))


def edge_pass_reference(values: np.ndarray, taps: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """values (H, W) blurred along the rows by ``taps`` (2 K + 1), each tap times the transmittances ``tau`` (H, W - 1)
    crossed, zero beyond the ends; plain numpy (the reference of :func:`synthesis.fields_fast.edge_pass`)."""
    width, reach = values.shape[1], len(taps) // 2
    out = taps[reach] * values
    right = left = np.ones(values.shape)  # products of the transmittances from each cell k to the right / left
    for k in range(1, min(reach, width - 1) + 1):
        right = right[:, : width - k] * tau[:, k - 1 :]
        left = left[:, 1:] * tau[:, : width - k]
        out[:, : width - k] += taps[reach + k] * right * values[:, k:]
        out[:, k:] += taps[reach - k] * left * values[:, : width - k]
    return out


def _tent_means(pixels: int, cells: int) -> np.ndarray:
    """(cells + 2 PAD, pixels): the mean over each of ``pixels`` equal intervals of an axis of the tent of each of its
    ``cells`` cells and the :data:`PAD` beyond (centred on the cell, one cell wide each side): ``M @ ink`` is the tent count
    that ink per pixel (uniform within each pixel) is expected to splat into each cell. Columns sum to 1."""
    def integral(u: np.ndarray) -> np.ndarray:  # of the tent max(1 - |t|, 0) from -inf to u
        u = np.clip(u, -1.0, 1.0)
        return np.where(u < 0, 0.5 * (u + 1) ** 2, 1.0 - 0.5 * (1 - u) ** 2)

    width = cells / pixels  # a pixel, in cells
    bounds = np.arange(pixels + 1) * width
    centres = np.arange(cells + 2 * PAD)[:, None] - PAD + 0.5
    steps = integral(bounds[None, :] - centres)
    return (steps[:, 1:] - steps[:, :-1]) / width


def _mirror(cells: int, reach: int) -> tuple[scipy.sparse.csr_matrix, np.ndarray]:
    """An axis of ``cells`` cells repeated mirrored ``reach`` cells beyond each end (``numpy.pad``'s "symmetric"): the
    sparse (cells + 2 reach, cells) matrix that does it and (cells + 2 reach,) the cell each mirrored cell repeats."""
    index = np.pad(np.arange(cells), reach, mode="symmetric")
    return scipy.sparse.csr_matrix((np.ones(len(index)), (np.arange(len(index)), index)), shape=(len(index), cells)), index


def _mirrored_tau(tau: tuple[np.ndarray, np.ndarray] | None, rows: np.ndarray, columns: np.ndarray):
    """:func:`transmittances` ``tau`` (across (H, W - 1), down (W, H - 1)) on the mirrored grid whose cells repeat the
    ``rows`` and ``columns`` of the grid (:func:`_mirror`): a cell and its mirror image pass all."""
    if tau is None:
        return None

    def seam(values: np.ndarray, index: np.ndarray) -> np.ndarray:  # between mirrored cells index[j], index[j + 1]
        a, b = index[:-1], index[1:]
        ones = np.ones((values.shape[0], 1))
        return np.concatenate([values, ones], axis=1)[:, np.where(a == b, values.shape[1], np.minimum(a, b))]

    across, down = tau
    return (np.ascontiguousarray(seam(across[rows], columns)), np.ascontiguousarray(seam(down[columns], rows)))


def _tent_filter(values: np.ndarray) -> np.ndarray:
    """values (H, W) correlated with :data:`TENT` along both axes, zero beyond the edges (``scipy.ndimage.correlate1d``
    with ``mode="constant"`` on each axis)."""
    for axis in (0, 1):
        padded = np.moveaxis(np.pad(values, [(1, 1) if a == axis else (0, 0) for a in (0, 1)]), axis, 0)
        values = np.moveaxis(TENT[0] * padded[:-2] + TENT[1] * padded[1:-1] + TENT[2] * padded[2:], 0, axis)
    return values
