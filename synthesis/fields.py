"""Per-map fields the edge-aware estimator and the synthesiser sample at points.

A :class:`MapFields` holds, on the map's pixel grid (area-averaged down to at
most :data:`FIELD_MAX_SIDE` pixels per side): the intensity (points per unit
area) implied by the density and the point count, the local spacing
``r_max(x)`` in which distances are measured, the latent correlation z (the
guide), and the target PCF and its count dispersion from the palette. It
evaluates the estimator's denominator at points
(:meth:`MapFields.denominator_at`: the tent counts a Poisson pattern of that
intensity gives around a point at x; exact where the neighbourhood is uniform,
closed-form border shares or polar quadrature elsewhere; it corrects the
domain border and sharp edges of density and correlation), and
:class:`DenominatorTracker` recomputes it only for points that moved.

Grids are (H, W, C) float32 numpy arrays; pixel (i, j) is centred at
((j + .5) / S, (i + .5) / S) with S = max(H, W), so the map covers
``[0, w] x [0, h]`` with max(w, h) = 1.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from synthesis.errors import PatternshopError
from synthesis.labmap import LabMap, pixels_of
from synthesis.palette import Palette
from synthesis.pcf import neighbour_cutoff, r_max, uniform_expectation

GUIDE_BANDWIDTH = 0.005  # variance of the guide (latent z) similarity, per dimension
DENSITY_FLOOR = 1e-3  # relative to the mean density: the intensity's floor (white areas expect almost no neighbours)
HOLD_MAX_SIDE = 1024  # the ink points are held to (:func:`nearest_ink`) is resolved on at most this many pixels per side
FIELD_MAX_SIDE = 256  # fields are computed on the map resampled to at most this many pixels per side
RING_STEP = 0.2  # quadrature: radial step between rings, in units of the local spacing (ring means are interpolated
# linearly onto the bins' 0.05 grid: the fields vary on the pixel scale, not on the bins'; 4x fewer nodes than one ring per bin)
RECOMPUTE_DISTANCE = 0.1  # a point's denominator is recomputed once it moved this many spacings (else linearised)
SLOPE_STEP = 0.25  # finite-difference step of the denominator's gradient, in units of the local spacing
RING_SPACING = 0.35  # quadrature: arc length between nodes on a ring, in units of the local spacing
UNIFORM_TOLERANCE = (0.02, 0.005)  # log-intensity and latent spreads below which a neighbourhood counts as uniform
# (the denominator then differs from the uniform value by well under 1 %: a linear trend cancels around the point)
POISSON_PAIR_SCALE = 2.0 / math.sqrt(3.0)  # intensity * r_max^2, the same at every density
STEP_RATIO = 2.0  # a pixel is on a density step where its density level (median filtered: LEVEL_MEDIAN) and one of its
# 8 neighbours' differ by more than this ratio: there the fields a point (or a quadrature node) is measured with are its pixel's, elsewhere bilinear
# (:meth:`MapFields.snapped`; docs/synthesis.md, "Density edges")
DENSITY_GUIDE = 0.32  # the guide's third coordinate, the density level, is this x ln(own intensity / its mean), median
# filtered (LEVEL_MEDIAN); differences within synthesis.fields_fast.LEVEL_DEAD_ZONE (0.16: intensity ratios up to 1.65)
# count 0, so a step of ratio 3.5 (L 15 | L 76) weighs its pairs H = 0.003, a ratio of 2 H = 0.68 (docs/synthesis.md,
# "Density edges")
LEVEL_MEDIAN = 2.0  # the density level is the median over a square of +- this many median spacings (at most
# LEVEL_MEDIAN_PX pixels): a texture finer than that (a photograph's grass, a textured map) is no guide edge, a step stays
# sharp; unfiltered, the level cost camera 0.9 dB of density PSNR at 1 spacing
LEVEL_MEDIAN_PX = 6
CORRELATION_STEP = 0.5  # a source pixel is on a sharp correlation edge where the guide H between its latent z and one
# of its 8 neighbours' is below this; a field pixel over such a pixel keeps one source pixel's chroma instead of a blend
# (:func:`_at_most`; docs/synthesis.md, "Outlines at correlation edges")
CORRELATION_REACH = math.sqrt(-2.0 * GUIDE_BANDWIDTH * math.log(CORRELATION_STEP))  # latent distance where H = that


def neighbour_gap(values: np.ndarray) -> np.ndarray:
    """(H, W) the largest Euclidean distance between an (H, W, C) array's values at a pixel and at one of its 8
    neighbours (edges repeated), in the values' units and dtype."""
    height, width = values.shape[:2]
    padded = np.pad(values, ((1, 1), (1, 1), (0, 0)), mode="edge")
    largest = np.zeros((height, width), values.dtype)
    for i in range(3):
        for j in range(3):
            gap = padded[i:i + height, j:j + width] - values
            np.maximum(largest, np.sqrt(np.sum(gap * gap, axis=-1)), out=largest)
    return largest


def step_pixels(log_level: np.ndarray) -> np.ndarray | None:
    """(H, W) bool: pixels of an (H, W) log intensity whose value and one of their 8 neighbours' (edges repeated) differ
    by more than ln :data:`STEP_RATIO` (a density step: a sharp edge of the map, not a soft gradient); None if none is."""
    step = neighbour_gap(log_level[..., None]) > math.log(STEP_RATIO)
    return step if step.any() else None


def correlation_step_pixels(latent: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels of an (H, W, 2) latent z whose guide H against one of their 8 neighbours' (edges repeated) is
    below :data:`CORRELATION_STEP` (a sharp correlation edge: a blend of the two sides is neither side)."""
    return neighbour_gap(latent) > CORRELATION_REACH


def sample_grid(grid: np.ndarray, xy: np.ndarray, side_px: int, out: np.ndarray | None = None) -> np.ndarray:
    """Bilinear samples (n, C) of a (H, W, C) grid at positions xy (n, 2) in map units (the grid's dtype).

    Positions outside the grid take the nearest edge value. ``out``: an (n, C)
    array of the grid's dtype to fill. A numba kernel; :func:`sample_grid_reference`
    is the plain version.
    """
    from synthesis.fields_fast import grid_samples

    xy = np.asarray(xy, np.float64)
    out = np.empty((len(xy), grid.shape[2]), grid.dtype) if out is None else out
    grid_samples(np.ascontiguousarray(grid), xy[:, 0] * side_px - 0.5, xy[:, 1] * side_px - 0.5, out)
    return out


def sample_table(table: np.ndarray, colour: np.ndarray, xy: np.ndarray, side_px: int) -> np.ndarray:
    """Bilinear samples (n, C) of the grid ``table[colour]`` (a (K, C) table's rows indexed per pixel by colour
    (H, W) int32) at positions xy (n, 2) in map units, the table's dtype: :func:`sample_grid` of that grid, the same
    values, without building it (a numba kernel)."""
    from synthesis.fields_fast import table_samples

    xy = np.asarray(xy, np.float64)
    out = np.empty((len(xy), table.shape[1]), table.dtype)
    table_samples(np.ascontiguousarray(table), colour, xy[:, 0] * side_px - 0.5, xy[:, 1] * side_px - 0.5, out)
    return out


def sample_grid_reference(grid: np.ndarray, xy: np.ndarray, side_px: int) -> np.ndarray:
    """Plain numpy version of :func:`sample_grid` (tests compare them)."""
    height, width, _ = grid.shape
    col = np.clip(xy[:, 0] * side_px - 0.5, 0, width - 1)
    row = np.clip(xy[:, 1] * side_px - 0.5, 0, height - 1)
    c0 = np.minimum(col.astype(np.int64), max(width - 2, 0))
    r0 = np.minimum(row.astype(np.int64), max(height - 2, 0))
    c1, r1 = np.minimum(c0 + 1, width - 1), np.minimum(r0 + 1, height - 1)
    tc, tr = (col - c0)[:, None], (row - r0)[:, None]
    top = grid[r0, c0] * (1 - tc) + grid[r0, c1] * tc
    bottom = grid[r1, c0] * (1 - tc) + grid[r1, c1] * tc
    return (top * (1 - tr) + bottom * tr).astype(grid.dtype)


def _area_matrix(old: int, new: int) -> np.ndarray:
    """(new, old) weights averaging ``old`` cells into ``new`` equal cells (exact fractional overlaps)."""
    edges = np.arange(new + 1) * (old / new)
    lo, hi = edges[:-1, None], edges[1:, None]
    cells = np.arange(old)[None, :]
    overlap = np.clip(np.minimum(hi, cells + 1) - np.maximum(lo, cells), 0.0, None)
    return overlap / overlap.sum(axis=1, keepdims=True)


def _at_most(lab_map: LabMap, side: int) -> LabMap:
    """The map area-averaged so its longer side has at most ``side`` pixels (same domain), except the chroma of a pixel
    over a sharp correlation edge (a source pixel of it on a :func:`correlation_step_pixels`): there it is its largest
    source pixel's. A blend of red and blue is neither: the logo's 384 px resampled to 256 had 812 pixels of 311
    blended colours along its edges, each with a palette PCF of its own (short-range level 0.3-2.9; blue's 0, red's 4.3)
    and guided weakly against both sides (docs/synthesis.md, "Outlines at correlation edges")."""
    longest = max(lab_map.width, lab_map.height)
    if longest <= side:
        return lab_map
    rows = _area_matrix(lab_map.height, max(1, round(lab_map.height * side / longest)))
    cols = _area_matrix(lab_map.width, max(1, round(lab_map.width * side / longest)))
    source = np.asarray(lab_map.lab, np.float64)
    lab = np.einsum("ih,hwc,jw->ijc", rows, source, cols, optimize=True)
    latent = np.asarray(lab_map.latent(), np.float64)
    if math.hypot(*np.ptp(latent.reshape(-1, 2), axis=0)) <= CORRELATION_REACH:  # one colour (a photograph): no edge
        return LabMap(lab.astype(np.float32))
    edge = correlation_step_pixels(latent).astype(np.float64)
    across = ((rows > 0) @ edge @ (cols > 0).T) > 0
    if across.any():
        largest = source[np.argmax(rows, axis=1)][:, np.argmax(cols, axis=1), 1:]  # each pixel's largest source pixel's
        lab[across, 1:] = largest[across]
    return LabMap(lab.astype(np.float32))


def nearest_ink(density: np.ndarray) -> tuple[np.ndarray | None, int]:
    """Where points may be: (H', W', 2) int32 (row, col) of the nearest pixel with ink (density > 0) of every pixel of
    a map's density (H, W) area-averaged to at most :data:`HOLD_MAX_SIDE` pixels per side (a pixel with any ink keeps
    some), and its pixels per map unit; None if every pixel has ink.
    """
    height, width = density.shape
    longest = max(height, width)
    if longest > HOLD_MAX_SIDE:
        rows = _area_matrix(height, max(1, round(height * HOLD_MAX_SIDE / longest)))
        cols = _area_matrix(width, max(1, round(width * HOLD_MAX_SIDE / longest)))
        density = rows @ density.astype(np.float64) @ cols.T
    ink = density > 0
    side_px = max(ink.shape)
    if ink.all() or not ink.any():
        return None, side_px
    from synthesis.fields_fast import nearest_true

    return nearest_true(ink), side_px


def _window_spread(values: np.ndarray, half: int) -> np.ndarray:
    """(H, W) max - min of values (H, W) over the square of ``2 half + 1`` pixels around each pixel, edges repeated:
    ``scipy.ndimage.maximum_filter - minimum_filter`` with ``mode="nearest"``, exactly (without importing scipy.ndimage)."""
    high, low = _window_extremes(values, half)
    return high - low


def _window_extremes(values: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) max and (H, W) min of values (H, W) over the square of ``2 half + 1`` pixels around each pixel, edges
    repeated (:func:`_window_spread`)."""
    size = 2 * half + 1
    extremes = []
    for pick in (np.maximum, np.minimum):
        out = values
        for axis in (0, 1):  # separable: along the columns, then the rows
            run = np.moveaxis(np.pad(out, [(half, half) if a == axis else (0, 0) for a in (0, 1)], mode="edge"), axis, 0)
            span = 1
            while 2 * span <= size:  # run[i]: the extreme of span padded values from i; doubled each step
                run = pick(run[:-span], run[span:])
                span *= 2
            length = out.shape[axis]
            out = np.moveaxis(pick(run[:length], run[size - span:size - span + length]), 0, axis)
        extremes.append(out)
    return extremes[0], extremes[1]


def guide_similarity(z_a: np.ndarray, z_b: np.ndarray, bandwidth: float = GUIDE_BANDWIDTH) -> np.ndarray:
    """Guidance term H = exp(-|z_a - z_b|^2 / (2 bandwidth)) over the last axis (latent z, then, if there, the density
    level, whose difference counts beyond :data:`synthesis.fields_fast.LEVEL_DEAD_ZONE`)."""
    from synthesis.fields_fast import LEVEL_DEAD_ZONE

    d = np.asarray(z_a - z_b, np.float64)
    if d.shape[-1] > 2:
        d = np.concatenate([d[..., :2], np.maximum(np.abs(d[..., 2:]) - LEVEL_DEAD_ZONE, 0.0)], axis=-1)
    return np.exp(-(d ** 2).sum(-1) / (2.0 * bandwidth))


@dataclass
class MapFields:
    """Fields of one map for n points (see the module docstring).

    Attributes:
        domain: (w, h).
        side_px: pixels per map unit (max(H, W)).
        n: number of points.
        intensity: (H, W, 1) points per unit area (floored at :data:`DENSITY_FLOOR` where the map has no ink).
        own_intensity: (H, W, 1) the intensity a point at x is measured against: ``intensity`` where the map has ink
            (density at least the floor), the nearest such pixel's elsewhere, so spacings stay bounded next to white.
        spacing: (H, W, 1) local r_max of ``own_intensity``.
        latent: (H, W, 2) latent correlation z in [0, 1].
        guide_z: (H, W, 3) float32 the guide's coordinates: z and :data:`DENSITY_GUIDE` x ln(own intensity / its mean),
            the density level (a density step is a guide edge, as a correlation edge is); sampled by :meth:`guide_at`.
        step: (H, W) bool, the pixel is on a density step (:func:`step_pixels` of the median-filtered level): fields are
            read there at the pixel's centre (:meth:`snapped`); None: nowhere.
        colour: (H, W) int32 the pixel's row in the colour tables: ``target_table`` (C, m) float32, the target PCF of
            each of the map's C distinct colours, and ``dispersion_table`` (C, m) float32, its count dispersion
            (variance model; :func:`synthesis.pcf.count_dispersion`); :attr:`target` and :attr:`dispersion` are the
            (H, W, m) grids they stand for, built only when asked for (the kernels sample the tables: 13.6 MB each at
            256^2 pixels and 52 radii, while a map's few colours stay in cache).
        uniform: (H, W) bool, the pixel's neighbourhood is uniform (see :meth:`_flat_pixels`).
        flat: (H, W) bool, the pixel's neighbourhood has one intensity and latent (it may touch the border).
        radii: (m,) radii in units of r_max.
        guide: whether the guidance term is used (False on a one-colour map, where it is 1 everywhere).
        nearest_ink: (H', W', 2) int32 or None, see :func:`nearest_ink` (None: ink everywhere) ...
        ink_side_px: ... its pixels per map unit.
        neighbour_table: (C, 2) float32 each colour's target's nearest-neighbour distances in r_max, lower and upper
            bound (:meth:`synthesis.palette.Palette.neighbour_bounds_at_latent`; None: not built).
    """

    domain: tuple[float, float]
    side_px: int
    n: int
    intensity: np.ndarray
    own_intensity: np.ndarray
    spacing: np.ndarray
    latent: np.ndarray
    colour: np.ndarray
    target_table: np.ndarray
    dispersion_table: np.ndarray
    uniform: np.ndarray
    flat: np.ndarray
    radii: np.ndarray
    guide: bool = True
    nearest_ink: np.ndarray | None = None
    ink_side_px: int = 1
    neighbour_table: np.ndarray | None = None
    guide_z: np.ndarray | None = None
    step: np.ndarray | None = None

    @classmethod
    def build(cls, lab_map: LabMap, n: int, palette: Palette, guide: bool = True) -> MapFields:
        """Precompute every field of ``lab_map`` for ``n`` points (``guide=False``: no guidance term).

        Maps larger than :data:`FIELD_MAX_SIDE` pixels per side are area-averaged
        down first; the fields are smooth on that scale and the denominator's
        cost grows with the pixel count.
        """
        from synthesis.fields_fast import LEVEL_DEAD_ZONE, nearest_true, running_median

        if n < 1:
            raise PatternshopError(f"point count must be at least 1, got {n}")
        w, h = lab_map.domain  # of the original map: resampling rounds the pixel counts
        nearest, ink_side_px = nearest_ink(lab_map.density())
        lab_map = _at_most(lab_map, FIELD_MAX_SIDE)
        density = lab_map.density().astype(np.float64)
        if not np.any(density > 0):
            raise PatternshopError("the map is white everywhere: there is nothing to place points on")
        inked = density >= DENSITY_FLOOR * density.mean()
        density = np.maximum(density, DENSITY_FLOOR * density.mean())
        intensity = n * density / (density.mean() * w * h)
        # where the map has no ink, a point is measured in the spacing of the nearest ink: with the floor's spacing
        # (30-80x larger) a point straying off a disc's edge took steps and a leash of that size and flew off into
        # the white (267 of 8,624 blue points on a 256 px disc)
        own = intensity if inked.all() else intensity[tuple(np.moveaxis(nearest_true(inked), -1, 0))]
        radii = np.asarray(palette.radii, np.float64)
        latent = np.ascontiguousarray(lab_map.latent(), np.float32)
        # maps have few distinct colours: look each up once (unique on the (a, b) pair's 8 bytes as one integer: a tenth
        # of the time of unique rows, 30-90 ms at 256^2 pixels)
        keys, pixel_colour = np.unique(latent.view(np.uint64), return_inverse=True)
        colours = keys.view(np.float32).reshape(-1, 2)
        pixel_colour = pixel_colour.reshape(latent.shape[:2]).astype(np.int32)
        # the level of the ink a point is measured against (off ink the nearest ink's, as its spacing: the floor's level
        # beside ink weighed a window centred on paper, or a point on a faint pixel, H = 0 against every neighbour and
        # their sums 0 / 0, NaN positions), median filtered (:data:`LEVEL_MEDIAN`)
        half = min(LEVEL_MEDIAN_PX, max(1, round(LEVEL_MEDIAN * float(np.median(r_max(own))) * max(lab_map.width, lab_map.height))))
        # separable (rows, then columns): a fifth of a square median's time, a straight step as sharp
        log_level = running_median(running_median(np.log(own / own.mean()), half).T, half).T
        level = DENSITY_GUIDE * log_level
        guide_z = np.ascontiguousarray(np.concatenate([latent, level[..., None]], axis=2), np.float32)
        fields = cls(
            domain=(w, h), side_px=max(lab_map.width, lab_map.height), n=n,
            intensity=intensity[..., None].astype(np.float32), own_intensity=own[..., None].astype(np.float32),
            spacing=r_max(own)[..., None].astype(np.float32),
            latent=latent, colour=pixel_colour, target_table=palette.pcf_at_latent(colours).astype(np.float32),
            dispersion_table=palette.dispersion_at_latent(colours).astype(np.float32),
            # one colour: every guide H is exp(0) = 1 (float32), so the guide's per-pair and per-window exponentials
            # are skipped (the same values: 100k points, 0.1-0.15 s of a run)
            uniform=np.empty(0, bool), flat=np.empty(0, bool), radii=radii,
            guide=guide and (len(keys) > 1 or not np.ptp(level) <= LEVEL_DEAD_ZONE), nearest_ink=nearest,
            ink_side_px=ink_side_px, neighbour_table=palette.neighbour_bounds_at_latent(colours).astype(np.float32),
            guide_z=guide_z, step=step_pixels(log_level),
        )
        flat, uniform = fields._flat_pixels()
        fields.flat, fields.uniform = flat & inked, uniform & inked  # off ink, the spacing is not the intensity's own
        return fields

    @functools.cached_property
    def target(self) -> np.ndarray:
        """(H, W, m) float32 the target PCF per pixel (``target_table[colour]``; the kernels sample the table)."""
        return self.target_table[self.colour]

    @functools.cached_property
    def dispersion(self) -> np.ndarray:
        """(H, W, m) float32 the target's count dispersion per pixel (``dispersion_table[colour]``)."""
        return self.dispersion_table[self.colour]

    def target_at(self, xy: np.ndarray) -> np.ndarray:
        """(n, m) float32 the target PCF at positions xy (n, 2), bilinear (:func:`sample_grid` of :attr:`target`)."""
        return sample_table(self.target_table, self.colour, xy, self.side_px)

    def dispersion_at(self, xy: np.ndarray) -> np.ndarray:
        """(n, m) float32 the count dispersion at positions xy (n, 2), bilinear (:func:`sample_grid` of :attr:`dispersion`)."""
        return sample_table(self.dispersion_table, self.colour, xy, self.side_px)

    def _flat_pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) bool each: the pixel's whole neighbourhood (cutoff x spacing) has one intensity and latent (flat),
        and in addition stays inside the domain (uniform).

        Square windows of power-of-two half-sizes, each pixel tested at the
        smallest one that covers its reach (conservative).
        """
        height, width, _ = self.intensity.shape
        reach = np.ceil(neighbour_cutoff(self.radii) * self.spacing[..., 0] * self.side_px + 1.0)
        channels = [np.log(self.intensity[..., 0]), self.latent[..., 0], self.latent[..., 1]]
        tolerances = (UNIFORM_TOLERANCE[0], UNIFORM_TOLERANCE[1], UNIFORM_TOLERANCE[1])
        # a channel whose spread over the whole map is within its tolerance is within it in every window (a window's
        # max - min is at most the map's, in floating point too): not tested (a constant map: 6 ms at 256^2 pixels)
        varied = [(c, tolerance) for c, tolerance in zip(channels, tolerances) if not c.max() - c.min() <= tolerance]
        rows, cols = np.indices((height, width))
        to_border = np.minimum(np.minimum(rows, height - 1 - rows), np.minimum(cols, width - 1 - cols))
        flat_pixels = np.zeros((height, width), bool)
        uniform = np.zeros((height, width), bool)
        half = 1
        while True:
            need = (reach <= half) & (reach > half // 2 if half > 1 else True)
            if need.any():
                flat = np.ones((height, width), bool)
                for channel, tolerance in varied:
                    flat &= _window_spread(channel, half) <= tolerance
                flat_pixels |= need & flat
                uniform |= need & flat & (to_border >= half)
            if half >= max(height, width) or half >= reach.max():
                return flat_pixels, uniform
            half *= 2

    def denominator_at(self, xy: np.ndarray, slope: bool = False):  # noqa: ANN201 - array or (array, array, array)
        """(n, m) ``int lambda(y) K_j(|y - x| / s(x)) H(z(y), z(x)) dy`` at points xy (n, 2).

        The tent counts a Poisson pattern of the map's intensity gives around a
        point at x. Points whose pixel has a uniform neighbourhood get the exact
        unbounded value ``lambda s^2 E_j`` (= 2/sqrt(3) E_j). Elsewhere polar
        quadrature around the point itself in units of s(x) (rings
        :data:`RING_STEP` apart, nodes :data:`RING_SPACING` apart along each
        ring; lambda = 0 outside the domain; z bilinear, lambda and the
        density level too except on a step pixel, where they are its own
        (:meth:`snapped`), exactly as the estimator samples them at the
        points: :meth:`guide_at`), divided by the same
        quadrature of the unbounded uniform case and times the exact value, so
        quadrature error cancels and only edges, borders and gradients move it.

        With ``slope=True`` also returns the indices (K,) of the points that are
        not uniform and the gradient (K, m, 2) of their denominator with respect
        to the point's position (s and z held at the point's values; forward
        differences of :data:`SLOPE_STEP` spacings). Without it, the estimator's
        gradient misses that a point moving away from a border or an edge gains
        expected neighbours, and points drift off borders and edges.
        """
        todo, values, gradient = self.nonuniform_denominators(xy, slope)
        out = np.broadcast_to(self.exact_denominator, (len(xy), len(self.radii))).copy()
        out[todo] = values
        return (out, todo, gradient) if slope else out

    @functools.cached_property
    def exact_denominator(self) -> np.ndarray:
        """(m,) the denominator in a uniform neighbourhood, ``lambda s^2 E_j`` (the same at every density)."""
        return POISSON_PAIR_SCALE * uniform_expectation(self.radii)

    def nonuniform_denominators(self, xy: np.ndarray, slope: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`denominator_at` for the points that need more than the exact value: their indices (K,) in xy (n, 2),
        values (K, m) and slopes (K, m, 2) (zeros unless ``slope``).

        Points whose neighbourhood is flat but crosses the domain border (every
        map has a border) get the exact value times the tent-weighted share of
        each quadrature ring inside the domain, computed in closed form
        (:func:`synthesis.fields_fast.border_shares`: no node noise, a fraction
        of the cost); the others (edges, gradients) get the polar quadrature.
        """
        xy = np.asarray(xy, np.float64)
        m = len(self.radii)
        row, col = pixels_of(xy, self.intensity.shape[:2], self.side_px)
        todo = np.flatnonzero(~self.uniform[row, col])
        values, gradient = np.empty((len(todo), m)), np.zeros((len(todo), m, 2))
        if not len(todo):
            return todo, values, gradient
        at = xy[todo]
        spacing = self.sample(self.spacing, at)[:, 0].astype(np.float64)
        border = self.flat[row[todo], col[todo]]
        general = ~border
        latent = self.guide_at(at[general])
        own = self.sample(self.own_intensity, at[general])[:, 0]

        def ratios(shift: np.ndarray) -> np.ndarray:
            out = np.empty((len(at), m))
            out[border] = self._border_ratio(at[border] + shift[border], spacing[border])
            out[general] = self._quadrature_at(at[general] + shift[general], spacing[general], latent, own)
            return out * self.exact_denominator

        values[:] = ratios(np.zeros_like(at))
        if slope:
            for axis in (0, 1):
                shift = np.zeros_like(at)
                shift[:, axis] = SLOPE_STEP * spacing
                gradient[..., axis] = (ratios(shift) - values) / (SLOPE_STEP * spacing)[:, None]
        return todo, values, gradient

    def _border_ratio(self, xy: np.ndarray, spacing: np.ndarray) -> np.ndarray:
        """(k, m) denominator ratio (1 away from the border) of points xy (k, 2) with spacing (k,) in a flat neighbourhood."""
        from synthesis.fields_fast import border_shares

        ring_tent, _ = self._rings
        height, width, _ = self.intensity.shape
        shares = border_shares(xy[:, 0], xy[:, 1], spacing, width / self.side_px, height / self.side_px, self._ring_radii)
        return (shares @ ring_tent) / ring_tent.sum(0)

    @functools.cached_property
    def _ring_radii(self) -> np.ndarray:
        """(R,) radii of the quadrature's rings, in units of the spacing."""
        return np.unique(self._quadrature[0])

    def _quadrature_at(self, xy: np.ndarray, spacing: np.ndarray, latent: np.ndarray, own: np.ndarray) -> np.ndarray:
        """(k, m) quadrature ratio (1 in a uniform neighbourhood) around points xy (k, 2) with spacing (k,), guide
        coordinates (k, 3) (:attr:`guide_z`), intensity (k,).

        The fused kernel of :mod:`synthesis.fields_fast`; :meth:`_quadrature_reference` is the plain version.
        """
        from synthesis.fields_fast import ring_means

        _, dx, dy, tent = self._quadrature
        ring_tent, node_ring = self._rings
        means = ring_means(self.intensity[..., 0].astype(np.float64), self._guide_planes, self._step_plane,
                           xy[:, 0] * self.side_px - 0.5,
                           xy[:, 1] * self.side_px - 0.5, spacing * self.side_px, np.ascontiguousarray(latent, np.float64),
                           own.astype(np.float64), dx, dy, node_ring,
                           len(ring_tent), self.guide, 2 if len(self.target_table) == 1 else 0, *self._reads(xy, spacing, latent[:, 2]),
                           GUIDE_BANDWIDTH)
        return (means @ ring_tent) / ring_tent.sum(0)

    def _reads(self, xy: np.ndarray, spacing: np.ndarray, level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What the quadrature around points xy (k, 2) with spacing (k,) and density level (k,) must read (the same values
        without the rest): (k,) int64 the guide coordinates up to 2 (z alone) where the level over every node's pixels
        stays within the dead zone of the point's (each node's level gap is 0), else 3; (k,) uint8 whether a :attr:`step`
        pixel lies within reach (else every node is bilinear). Reading both at every node made camera's quadrature 6x
        as long."""
        from synthesis.fields_fast import LEVEL_DEAD_ZONE

        if self.step is None and not self.guide:  # neither is read
            return np.full(len(xy), 2, np.int64), np.zeros(len(xy), np.uint8)
        half, high, low, steps = self._reach_boxes
        u = self._quadrature[0]
        reach = (u.max() + SLOPE_STEP) * spacing * self.side_px + 2.0  # pixels: nodes, the unshifted point, bilinear support
        box = np.minimum(np.searchsorted(half, reach), len(half) - 1)
        row, col = pixels_of(xy, high.shape[1:], self.side_px)
        inside = reach <= half[box]
        flat = inside & (high[box, row, col] - level <= LEVEL_DEAD_ZONE) & (level - low[box, row, col] <= LEVEL_DEAD_ZONE)
        return np.where(flat, 2, 3).astype(np.int64), (~inside | steps[box, row, col]).astype(np.uint8)

    @functools.cached_property
    def _reach_boxes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Half-widths (K,) 1, 2, 3, 4, 6, 8, 11, ... pixels (steps of sqrt 2); (K, H, W) float32 the density level's
        max and min, and (K, H, W) bool whether a :attr:`step` pixel lies, in the box of each half-width around each
        pixel (:meth:`_reads`)."""
        level = self.guide_z[..., 2]
        half = np.unique(np.round(2.0 ** (np.arange(2 * int(math.log2(max(level.shape))) + 3) / 2)).astype(np.int64))
        high, low = (np.stack(planes) for planes in zip(*(_window_extremes(level, int(h)) for h in half)))
        counts = np.zeros((level.shape[0] + 1, level.shape[1] + 1))  # summed-area table of the step pixels
        if self.step is not None:
            np.cumsum(np.cumsum(self.step, axis=0), axis=1, out=counts[1:, 1:])
        rows, cols = np.arange(level.shape[0]), np.arange(level.shape[1])
        steps = []
        for h in half:
            r0, r1 = np.clip(rows - h, 0, len(rows)), np.clip(rows + h + 1, 0, len(rows))
            c0, c1 = np.clip(cols - h, 0, len(cols)), np.clip(cols + h + 1, 0, len(cols))
            steps.append((counts[r1][:, c1] - counts[r0][:, c1] - counts[r1][:, c0] + counts[r0][:, c0]) > 0)
        return half.astype(np.float64), high, low, np.stack(steps)

    @functools.cached_property
    def _step_plane(self) -> np.ndarray:
        """(H, W) uint8 :attr:`step` for the quadrature's kernel ((0, 0): no step)."""
        return np.zeros((0, 0), np.uint8) if self.step is None else self.step.astype(np.uint8)

    @functools.cached_property
    def _guide_planes(self) -> np.ndarray:
        """(3, H, W) float64 :attr:`guide_z`, one contiguous plane per coordinate (the quadrature's kernel reads them)."""
        return np.ascontiguousarray(np.moveaxis(self.guide_z, -1, 0), np.float64)

    @functools.cached_property
    def _rings(self) -> tuple[np.ndarray, np.ndarray]:
        """Tent weights x ring area (R, m) of the quadrature's rings and the ring of every node (Q,) int64."""
        u, _, _, tent = self._quadrature
        radii, node_ring = np.unique(u, return_inverse=True)
        ring_tent = np.zeros((len(radii), tent.shape[1]))
        np.add.at(ring_tent, node_ring, tent)
        return ring_tent, node_ring.astype(np.int64)

    def _quadrature_reference(self, xy: np.ndarray, spacing: np.ndarray, latent: np.ndarray, own: np.ndarray) -> np.ndarray:
        """Plain numpy/scipy version of :meth:`_quadrature_at` (tests compare them)."""
        from scipy import ndimage

        from synthesis.fields_fast import LEVEL_DEAD_ZONE

        height, width, _ = self.intensity.shape
        _, dx, dy, tent = self._quadrature
        free = tent.sum(0)
        result = np.empty((len(xy), tent.shape[1]))
        spacing_px = spacing * self.side_px
        px0, py0 = xy[:, 0] * self.side_px - 0.5, xy[:, 1] * self.side_px - 0.5  # pixel-index coordinates
        chunk = max(1, 1_000_000 // len(dx))
        for start in range(0, len(xy), chunk):
            block = slice(start, start + chunk)
            px = px0[block, None] + spacing_px[block, None] * dx[None]
            py = py0[block, None] + spacing_px[block, None] * dy[None]
            inside = (px >= -0.5) & (px <= width - 0.5) & (py >= -0.5) & (py <= height - 0.5)
            coords = np.stack([py.reshape(-1), px.reshape(-1)])
            snapped = coords.copy()  # lambda and the density level: a step pixel's own value on it (:meth:`snapped`)
            if self.step is not None:
                pixel = np.clip(np.floor(coords + 0.5).astype(np.int64), 0, np.array([[height - 1], [width - 1]]))
                on = self.step[pixel[0], pixel[1]]
                snapped[:, on] = pixel[:, on]

            def bilinear(plane: np.ndarray, at: np.ndarray) -> np.ndarray:
                return ndimage.map_coordinates(plane, at, order=1, mode="nearest").reshape(py.shape)

            weight = bilinear(self.intensity[..., 0], snapped) * inside / own[block, None]
            if self.guide:
                squares = np.maximum(np.abs(bilinear(self.guide_z[..., 2], snapped) - latent[block, 2:]) - LEVEL_DEAD_ZONE,
                                     0.0) ** 2
                for c in range(2):  # the latent z: bilinear
                    squares = squares + (bilinear(self.guide_z[..., c], coords) - latent[block, c:c + 1]) ** 2
                weight = weight * np.exp(-squares / (2 * GUIDE_BANDWIDTH))
            result[block] = (weight @ tent) / free
        return result

    @functools.cached_property
    def _quadrature(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Polar nodes in units of the spacing: radii u (Q,), offsets dx, dy (Q,), tent weights x area (Q, m).

        The tents are integrated on a fine radial grid (half a bin apart); the
        integrand's ring mean there is interpolated linearly from rings
        :data:`RING_STEP` apart, which carry the nodes (:data:`RING_SPACING`
        apart along each ring). A node's weight is its ring's share of the
        interpolated tent integrals.
        """
        width_bin = float(self.radii[1] - self.radii[0])
        reach = self.radii[-1] + width_bin
        fine_step = 0.5 * width_bin
        fine = np.arange(0.5 * fine_step, reach, fine_step)
        fine_tent = np.clip(1 - np.abs(fine[:, None] - self.radii[None, :]) / width_bin, 0, None) * (2 * math.pi * fine * fine_step)[:, None]
        rings = np.arange(0.5 * RING_STEP, reach + RING_STEP, RING_STEP)
        spread = np.stack([np.interp(fine, rings, np.eye(len(rings))[k]) for k in range(len(rings))], axis=1)  # (F, R)
        ring_tent = spread.T @ fine_tent  # (R, m)
        nodes = []
        for u, weights in zip(rings, ring_tent):
            count = max(8, math.ceil(2 * math.pi * u / RING_SPACING))
            theta = (np.arange(count) + 0.5) * (2 * math.pi / count)
            nodes.append((np.full(count, u), u * np.cos(theta), u * np.sin(theta), np.broadcast_to(weights / count, (count, len(weights)))))
        u, dx, dy, tent = (np.concatenate(part) for part in zip(*nodes))
        return u, dx, dy, tent

    # --- sampling at points -------------------------------------------------
    def snapped(self, xy: np.ndarray) -> np.ndarray:
        """(n, 2) positions xy (n, 2) in map units, those on a :attr:`step` pixel moved to its centre: bilinear samples
        there are the pixel's own value (the map's density is constant on each pixel, and a bilinear sample spreads a
        step over a pixel: within half a pixel of it a light point had a dark point's spacing; docs/synthesis.md,
        "Density edges"), elsewhere they blend as before (a photograph's soft gradients)."""
        if self.step is None:
            return xy
        row, col = pixels_of(xy, self.step.shape, self.side_px)
        on = self.step[row, col]
        out = np.array(xy, np.float64)
        out[on, 0], out[on, 1] = (col[on] + 0.5) / self.side_px, (row[on] + 0.5) / self.side_px
        return out

    def sample(self, grid: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """(n, C) samples of a (H, W, C) field at positions xy (n, 2): bilinear, a step pixel's own value on it
        (:meth:`snapped`)."""
        return sample_grid(grid, self.snapped(xy), self.side_px)

    def guide_at(self, xy: np.ndarray) -> np.ndarray:
        """(n, 3) float64 the guide coordinates at positions xy (n, 2): z bilinear (a correlation edge's blend is
        measured with it), the density level as the spacing (:meth:`sample`)."""
        out = np.empty((len(xy), 3))
        out[:, :2] = sample_grid(self.latent, xy, self.side_px)
        out[:, 2] = self.sample(self.guide_z[..., 2:], xy)[:, 0]
        return out

    def at(self, xy: np.ndarray, denominator: bool = True) -> dict[str, np.ndarray]:
        """Fields at positions xy (n, 2): spacing (n,), latent (n, 2), target, dispersion and (optionally) denominator (n, m)."""
        fields = {
            "spacing": self.sample(self.spacing, xy)[:, 0],
            "latent": sample_grid(self.latent, xy, self.side_px),
            "target": self.target_at(xy),
            "dispersion": self.dispersion_at(xy),
        }
        if denominator:
            fields["denominator"] = self.denominator_at(xy)
        return fields


@dataclass
class Denominators:
    """Poisson denominators of n points: :attr:`MapFields.exact_denominator` for most, stored rows for the others.

    Attributes:
        exact: (m,) the value in a uniform neighbourhood.
        slot: (n,) int32, -1 for a point in a uniform neighbourhood, else its row in ``values`` and ``slopes``
            (rows in increasing point order).
        values: (K, m) float64 at the points' current positions.
        slopes: (K, m, 2) float32 gradient with respect to the point's position (the tracker's own array).
    """

    exact: np.ndarray
    slot: np.ndarray
    values: np.ndarray
    slopes: np.ndarray

    @property
    def sloped(self) -> np.ndarray:
        """(K,) indices of the points with a stored row (near borders and edges), in row order."""
        return np.flatnonzero(self.slot >= 0)

    def full(self) -> np.ndarray:
        """(n, m) every point's denominator."""
        out = np.broadcast_to(self.exact, (len(self.slot), len(self.exact))).copy()
        out[self.slot >= 0] = self.values
        return out


class DenominatorTracker:
    """Denominators and their slopes at a moving pattern, recomputed only for points that moved.

    :meth:`update` recomputes (:meth:`MapFields.nonuniform_denominators`) the
    points that moved more than :data:`RECOMPUTE_DISTANCE` spacings since their
    last evaluation and carries the others forward along their slope. Memory
    follows the points near borders and edges (K), not n x m.
    """

    def __init__(self, fields: MapFields):
        self.fields = fields
        self.anchor: np.ndarray | None = None

    def update(self, xy: np.ndarray) -> Denominators:
        """:class:`Denominators` at xy (n, 2)."""
        xy = np.asarray(xy, np.float64)
        m = len(self.fields.radii)
        if self.anchor is None or len(self.anchor) != len(xy):
            moved = np.ones(len(xy), bool)
            self.anchor = xy.copy()
            self.slot = np.full(len(xy), -1, np.int32)
            self.values, self.slopes = np.empty((0, m)), np.empty((0, m, 2), np.float32)
        else:
            spacing = self.fields.sample(self.fields.spacing, xy)[:, 0]
            moved = np.linalg.norm(xy - self.anchor, axis=1) > RECOMPUTE_DISTANCE * spacing
        computed, values, slopes = self.fields.nonuniform_denominators(xy[moved])
        computed = np.flatnonzero(moved)[computed]
        kept = np.flatnonzero(~moved & (self.slot >= 0))
        stored = np.union1d(kept, computed)  # sorted: rows in point order
        slot = np.full(len(xy), -1, np.int32)
        slot[stored] = np.arange(len(stored), dtype=np.int32)
        new_values, new_slopes = np.empty((len(stored), m)), np.empty((len(stored), m, 2), np.float32)
        new_values[slot[kept]], new_slopes[slot[kept]] = self.values[self.slot[kept]], self.slopes[self.slot[kept]]
        new_values[slot[computed]], new_slopes[slot[computed]] = values, slopes
        self.anchor[moved] = xy[moved]
        self.slot, self.values, self.slopes = slot, new_values, new_slopes
        current = new_values + np.einsum("kjd,kd->kj", new_slopes.astype(np.float64), xy[stored] - self.anchor[stored])
        np.maximum(current, 0.0, out=current)  # an expected count: the linear carry overshot below 0 (min -0.68 on a 28-point map)
        return Denominators(self.fields.exact_denominator, slot, current, new_slopes)
