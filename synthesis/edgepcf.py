"""The edge-aware PCF estimator (paper §5) and the synthesis objective with its gradient.

Around a point c of the pattern (a centre), with the local spacing
s(c) = r_max at c, neighbours k within reach are tent-counted (see
:mod:`synthesis.pcf`) at the radii rho_j, each pair weighted by the guidance
term H(z(x_k), z(x_c)) on the latent correlation z:

    S(c, j) = sum_k tent_j(|x_k - x_c| / s(c)) H(z_k, z_c)
    g_hat(c, j) = S(c, j) / D(c, j)

where D is the Poisson denominator of :class:`~synthesis.fields.MapFields`
(the same counts for a Poisson pattern of the map's intensity; it corrects
borders and edges of density and correlation). For an (inhomogeneous) Poisson
pattern E[g_hat] = 1 everywhere.

**The objective aggregates** (our change to paper eq. 6, which matches each
centre's own PCF). One point's neighbourhood holds a handful of pairs per
radius, so its own PCF varies a lot between neighbourhoods of a true sample;
forcing every one to the target makes patterns over-regular. Instead the
pair-count excess ``e(c, j) = S(c, j) - g(c, j) D(c, j)`` is cumulated over the
radii, ``E(c, j) = sum_{i <= j} e(c, i)`` (pairs closer than each radius: every
step out of a hard core pays), and summed over guided windows of centres,
``r(w, j) = sum_c a_wc E(c, j)`` with ``a_wc = taper(|x_c - x_w| / (R s(w))) H(z_c, z_w)``
(:func:`window_taper`). Window centres are drawn with the map's intensity,
independently of the pattern (:class:`WindowSampler`). Each family of
:data:`WINDOW_SCALES` (local windows, R = 3.3 spacings, one per 8 points;
regional ones, R = 16, one per 200 points) standardises its sums by their
Poisson-model standard deviation ``sigma(w, j)`` (:func:`_deviation`, growth
from :data:`CUMULATIVE_VARIANCE`) and scores them with its dead zone b
(:func:`dead_zone`; b = 2 local, b = 0 regional, i.e. plain quadratic):

    L = sum_families weight / (W m) sum_{w, j} max(|r(w, j)| / sigma(w, j) - b, 0)^2
        + the regional windows' variance compensation (:func:`_variance_force`)

Local windows leave a true sample's natural variation inside the dead zone and
catch outliers (holes, stacks, broken hard cores); regional windows match the
PCF's mean with too few constraints to fit a sample's noise. Stacked or
too-close pairs fall in the small-radius bins where the target expects none,
and cost. The gradient is written out by hand (chain rule through the pair
distances; window weights, deviations, fields and H are held fixed between
neighbour refreshes, the expected counts near borders and edges linearised),
so memory stays O(pairs). That linear change of the expected counts with a
point's position follows the pattern's own pair level, not the target's
(:func:`slope_levels`): otherwise a pattern short of its pairs gains by moving
towards borders and edges, where fewer are expected. At correlation edges it moves
towards the pattern's measured pair derivative (:func:`edge_slope_levels`): a pair
counts around both of its points, so a move changes the counts about twice as much
as the point's own expected slope says.

Two implementations: :func:`objective_reference` (plain numpy, the reference
the tests compare against) and the fused numba kernels of
:mod:`synthesis.edgepcf_fast`, used by the synthesiser.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from synthesis.cells import CellGrid
from synthesis.edgepcf_fast import (WINDOW_PARTS, cumulate, expected_window_sums, point_lists, point_terms, row_guides,
                                    sloped_window_sums, window_bounds, window_sums, window_totals, window_weights)
from synthesis.fields import GUIDE_BANDWIDTH, DenominatorTracker, Denominators, MapFields, sample_grid, sample_table
from synthesis.labmap import LabMap, pixels_of
from synthesis.palette import Palette
from synthesis.pcf import neighbour_cutoff
from synthesis.stratified import StratifiedSampler
from synthesis.workspace import Workspace, scratch

CUMULATIVE_VARIANCE = (1.0, 5.0)  # Var / (sum a^2 K) of a window's cumulative count at radius rho: 1 + 5 rho (Poisson, measured)
REGULAR_RANGE = 0.55  # radii (units of r_max) over which the target's short-range PCF measures its regularity
POISSON_TOLERANCE = 0.1  # a target PCF within this of 1 at every radius is white noise (exemplar noise is ~0.07)
STRUCTURE_RANGE = 0.4  # ... and from this much further on, a structured one
VARIANCE_FLOOR = 0.05  # pairs^2: one stray pair where the target expects none is 4.5 standard deviations
LEVEL_PRIOR = 0.5  # pairs per point added to both sums of a window's pair level (:func:`slope_levels`): 1 where none expected
EDGE_GUIDE = 0.5  # a sloped point with a pair guided below this lies at a correlation edge (:func:`edge_slope_levels`)
EDGE_SLOPE_SHARE = 0.5  # share of the pair-derivative correction that the slopes there take (measured, see the function)
EDGE_SLOPE_MAX = 3.0  # a window's measured ratio of pair derivative to model slope is clipped to [0, this]
TROUGH_RANGE = (0.5, 1.5)  # radii (r_max) between a clustered target's clusters, where green's PCF dips to 0.21 (red: >= 1.56)
TROUGH_LEVEL, TROUGH_DEPTH = 0.9, 0.4  # a trough below 0.9 counts (Matern's 0.98 and white's 0.97 do not), fully at 0.5


@dataclass(frozen=True)
class WindowScale:
    """One family of aggregation windows and how its deviations are scored.

    Attributes:
        radius: window radius in units of the spacing at the window's centre.
        points_per_window: windows per refresh = n / this (windows overlap: radius^2 > this).
        dead_zone: standardised deviations within this many standard deviations cost nothing.
        weight: the family's weight in the objective.
        compensation: factor of the variance compensation (see :func:`_variance_force`; measured).
        level: its windows measure the pattern's pair level that the expected counts' slopes follow (see
            :func:`slope_levels`).
    """

    radius: float
    points_per_window: float
    dead_zone: float
    weight: float
    compensation: float = 0.0
    level: bool = False


# Local windows (~40 points) catch outliers (holes, stacks, broken hard cores) and leave a true
# sample's natural variation alone; regional windows (~900 points) match the PCF's mean exactly,
# with few enough constraints (n / 200 windows) that they cannot fit a sample's noise.
# Both score cumulative counts (pairs closer than each radius: every step out of a hard core pays).
WINDOW_SCALES = (WindowScale(radius=3.3, points_per_window=8.0, dead_zone=2.0, weight=1.0),
                 WindowScale(radius=16.0, points_per_window=200.0, dead_zone=0.0, weight=1.0, compensation=2.0,
                             level=True))


@dataclass
class Windows:
    """Aggregation windows of one scale (membership lists).

    Attributes:
        scale: the :class:`WindowScale`.
        offsets: (W + 1,) int64; members of window w are ``offsets[w]:offsets[w + 1]`` ...
        members: (M,) int32 ... these points ...
        weights: (M,) float32 ... with these weights (taper x guide).
        deviation: (W, m) float32 standard deviation of each window's cumulative count (Poisson model).
    """

    scale: WindowScale
    offsets: np.ndarray
    members: np.ndarray
    weights: np.ndarray
    deviation: np.ndarray

    @property
    def owners(self) -> np.ndarray:
        """(M,) window of each membership entry."""
        return _owners(self.offsets)

    def aggregate(self, values: np.ndarray) -> np.ndarray:
        """Window sums (W, m) of per-point values (n, m): ``sum_c a_wc values_c``."""
        out = np.zeros((len(self.offsets) - 1, values.shape[1]))
        np.add.at(out, self.owners, self.weights[:, None] * values[self.members])
        return out

    def distribute(self, values: np.ndarray, n: int) -> np.ndarray:
        """Per-point sums (n, m) of per-window values (W, m): the adjoint of :meth:`aggregate`."""
        out = np.zeros((n, values.shape[1]))
        np.add.at(out, self.members, self.weights[:, None] * values[self.owners])
        return out


@dataclass
class Neighbourhoods:
    """Pair lists of every point, aggregation windows, and the fields at the points (refreshed every few steps).

    Attributes:
        offsets: (n + 1,) int64; pairs of centre c are ``offsets[c]:offsets[c + 1]``.
        neighbours: (P,) int32 neighbour of each pair (within the cutoff of its centre).
        guide: (P,) float32 guidance weights H of the pairs.
        spacing: (n,) local r_max at the points.
        anchor: (n, 2) the positions at the refresh, where the expected counts ``g D`` are taken
            (:meth:`expected`: the target sampled there, times ``denominators``: rows of ``target_table`` (C, m)
            indexed per pixel by ``colour`` (H, W), ``side_px`` pixels per map unit, as :class:`MapFields` holds it);
            for points near borders and edges ...
        sloped: (K,) int64 ... (these) the expected counts change with position ...
        expected_slope: (K, m, 2) ... by ``g grad D`` (linearised between refreshes).
        variance_force: (K, 2) gradient of the variance compensation at the sloped points (see :func:`_variance_force`).
        windows: one :class:`Windows` per :data:`WINDOW_SCALES` entry ...
        member_offsets: (n + 1,) int64 ... and the windows each point belongs to (transposed lists, all families,
            windows numbered family after family): ``member_offsets[c]:member_offsets[c + 1]`` ...
        member_window: (E,) int32 ... these windows ...
        member_weight: (E,) float32 ... with these weights.
        radii: (m,) radii in units of r_max.
        regularity: (n,) in [0, 1], how far the target PCF at each point stays below 1 at short range.
        structure: (n,) in [0, 1], how far the target PCF at each point is from Poisson's (0: white noise).
        window_expected: (W, m) float64 every window's sum of its points' expected counts ``sum_c a_wc g D_c`` at the
            anchors, per radius (all families, numbered as the point lists; :func:`synthesis.edgepcf_fast.window_sums`).
        deviation: (W, m) float32 every window's deviation, numbered as the point lists (the families' ``deviation``
            are views of it).
        anchor_counts: the buffers (per-thread window sums of the tent counts, each pair's bin and pull) in which
            :func:`synthesis.edgepcf_fast.window_sums` left its counts at the anchors, while they are intact: the
            objective's first evaluation there reads them instead of counting again (None: count).
        guided: False where every ``guide`` is 1 (a one-colour map): the kernels then do not read them.
    """

    offsets: np.ndarray
    neighbours: np.ndarray
    guide: np.ndarray
    spacing: np.ndarray
    anchor: np.ndarray
    target_table: np.ndarray
    colour: np.ndarray
    side_px: int
    denominators: Denominators
    sloped: np.ndarray
    expected_slope: np.ndarray
    variance_force: np.ndarray
    windows: list[Windows]
    member_offsets: np.ndarray
    member_window: np.ndarray
    member_weight: np.ndarray
    radii: np.ndarray
    regularity: np.ndarray
    structure: np.ndarray
    window_expected: np.ndarray | None = None
    deviation: np.ndarray | None = None
    anchor_counts: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    guided: bool = True

    def expected(self) -> np.ndarray:
        """(n, m) float64 target tent counts ``g D`` around each point at its anchor (plain numpy)."""
        return sample_table(self.target_table, self.colour, self.anchor, self.side_px).astype(np.float64) * self.denominators.full()

    @property
    def centres(self) -> np.ndarray:
        """(P,) centre of each pair."""
        return _owners(self.offsets)


def _owners(offsets: np.ndarray) -> np.ndarray:
    return np.repeat(np.arange(len(offsets) - 1, dtype=np.int32), np.diff(offsets))


def window_taper(u: np.ndarray) -> np.ndarray:
    """Smooth window weight ``(1 - u^2)^2`` for distances u < 1 in units of the window radius, else 0."""
    q = np.clip(1.0 - np.asarray(u) ** 2, 0.0, None)
    return q * q


class WindowSampler:
    """Window centres for every scale, stratified with the map's intensity (independent of any pattern)."""

    def __init__(self, fields: MapFields):
        self.n = fields.n
        self.sampler = StratifiedSampler(fields.intensity[..., 0], fields.side_px, fields.domain, fields.n)

    def draw(self, rng: np.random.Generator) -> list[np.ndarray]:
        """One (W, 2) array of centres per :data:`WINDOW_SCALES` entry."""
        return [self.sampler.draw(max(1, round(self.n / scale.points_per_window)), rng) for scale in WINDOW_SCALES]


def _windows(scale: WindowScale, fields: MapFields, grid: CellGrid, latent: np.ndarray, centres: np.ndarray,
             workspace: Workspace, name: str) -> Windows:
    """Members and weights of windows at ``centres`` (W, 2); their deviation is set by :func:`find_neighbourhoods`."""
    reach = scale.radius * fields.sample(fields.spacing, centres)[:, 0].astype(np.float64)
    # the distances, needed only here, in the buffer the refresh's window sums take later (1M points: 39 MB less)
    offsets, members, distance = grid.query(centres, reach, workspace=workspace, name=name, distance_name=WINDOW_PARTS)
    centre_latent = sample_grid(fields.latent, centres, fields.side_px) if fields.guide else None
    weights = window_weights(distance, offsets, reach, latent, members, centre_latent, GUIDE_BANDWIDTH,
                             workspace.empty(f"{name}.weights", len(members), np.float32))
    return Windows(scale, offsets, members, weights, np.empty(0))


def _deviation(scale: WindowScale, squares: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(W, m) float32 standard deviation of windows' cumulative counts from their sums of ``a^2 V`` (W, m).

    Dead-zone windows need the true spread (it sets the zone); quadratic ones only a weight per radius, kept flat
    so that the large radii, whose counts vary most, still count (they carry a blue pattern's second shell).
    """
    growth = CUMULATIVE_VARIANCE[1] if scale.dead_zone else 0.0
    factor = CUMULATIVE_VARIANCE[0] + growth * (radii + (radii[1] - radii[0]))
    # guard: each a^2 V is >= 0 once DenominatorTracker keeps its carried denominators >= 0; before that, a map
    # lightened to 28 points (training item 1814) gave sums down to -57 and the square root's NaN spread into the
    # points' positions
    return np.sqrt(np.maximum(factor * squares, 0.0) + VARIANCE_FLOOR).astype(np.float32)


def find_neighbourhoods(fields: MapFields, xy: np.ndarray, window_centres: list[np.ndarray] | None = None,
                        denominators: DenominatorTracker | None = None, workspace: Workspace | None = None,
                        slopes: bool = True) -> Neighbourhoods:
    """Every pair within the estimator's reach (cutoff x spacing of the centre), windows, and the fields at the points.

    ``window_centres``: one (W, 2) array per :data:`WINDOW_SCALES` entry, where the
    windows sit; they must not depend on the pattern (default: a fixed-seed
    :class:`WindowSampler` draw; the synthesiser draws new ones at every refresh).
    ``denominators``: a tracker that recomputes only moved points (default: all computed).
    ``workspace``: where the large arrays live (a synthesiser reuses one across refreshes:
    the previous neighbourhoods' arrays are overwritten). Neighbour lists come from one :class:`~synthesis.cells.CellGrid` with cells of
    the median pair reach; they run fastest on spatially sorted points.
    ``slopes=False``: the expected counts' slopes and the variance force are left 0 (no slope levels, no window sums of
    counts): only for the objective at xy itself, where every slope term meets a move of 0 (the same loss;
    :func:`synthesis.synthesize.final_loss`).
    """
    xy = np.asarray(xy, np.float64)
    n = len(xy)
    if window_centres is None:
        window_centres = WindowSampler(fields).draw(np.random.default_rng(0))
    workspace = scratch(workspace)
    denominator = (denominators or DenominatorTracker(fields)).update(xy)
    spacing = fields.sample(fields.spacing, xy)[:, 0].astype(np.float64)
    latent = fields.guide_at(xy)
    reach = neighbour_cutoff(fields.radii) * spacing
    grid = CellGrid(xy, fields.domain, float(np.median(reach)))
    offsets, neighbours, _ = grid.query(xy, reach, exclude=np.arange(n), distances=False, workspace=workspace, name="pairs")
    guide = workspace.empty("pairs.guide", len(neighbours), np.float32)
    if fields.guide:
        row_guides(latent, latent, offsets, neighbours, GUIDE_BANDWIDTH, out=guide)
    else:
        guide.fill(1.0)
    z = np.ascontiguousarray(latent[:, :2])  # windows weigh their members by the latent z alone: with the density level
    # too, camera's density PSNR at 1 spacing read 29.83 dB against 30.13 (docs/synthesis.md, "Density edges")
    windows = [_windows(scale, fields, grid, z, where, workspace, f"windows{i}")
               for i, (scale, where) in enumerate(zip(WINDOW_SCALES, window_centres))]
    members = point_lists(windows, n, workspace)
    bounds = window_bounds(windows)
    squares, regular, structured = point_terms(fields, xy, denominator, members, bounds[-1],
                                               int(np.sum(fields.radii <= REGULAR_RANGE)), POISSON_TOLERANCE, STRUCTURE_RANGE,
                                               workspace=workspace)
    deviation = np.empty(squares.shape, np.float32)
    for family, lo, hi in zip(windows, bounds[:-1], bounds[1:]):
        family.deviation = deviation[lo:hi]
        family.deviation[:] = _deviation(family.scale, squares[lo:hi], fields.radii)
    sloped = denominator.sloped
    if slopes:
        # the expected counts' slopes g grad D cumulated over the radii (K, m, 2), in place (as the levels below: 1M
        # points, 2 threads, 52 MB less at a refresh)
        cumulative = fields.target_at(xy[sloped]).astype(np.float64)[..., None] * denominator.slopes
        cumulate(cumulative)  # np.cumsum(cumulative, axis=1, out=cumulative), faster
        dispersion = fields.dispersion_at(xy[sloped])
        variance_force = _variance_force(windows, members, sloped, dispersion[..., None] * cumulative, fields.radii)
    else:
        cumulative, variance_force = np.zeros((len(sloped), len(fields.radii), 2)), np.zeros((len(sloped), 2))
    hood = Neighbourhoods(offsets, neighbours, guide, spacing, xy.copy(), fields.target_table, fields.colour, fields.side_px,
                          denominator, sloped, cumulative, variance_force, windows, *members,
                          np.asarray(fields.radii, np.float64), regular, structured, deviation=deviation,
                          guided=fields.guide)  # expected_slope set below (window_sums does not read it)
    if not slopes:
        hood.window_expected = expected_window_sums(hood, workspace)
        return hood
    observed, hood.window_expected = window_sums(hood, xy, workspace, level_only=True)
    if len(sloped):
        levels = slope_levels(hood, observed, hood.window_expected)
        if hood.guided:  # correlation edges: the slopes follow the pattern's own pair derivative there
            levels = edge_slope_levels(hood, cumulative, levels)
        cumulative *= levels[..., None]  # levelled
        hood.expected_slope = _by_axis(cumulative.shape)  # the fast objective takes each axis's (K, m) as they are
        for axis in (0, 1):  # np.diff, prepend=0, one axis at a time into its contiguous (K, m) (10k: 1.5 -> 0.3 ms)
            slope = hood.expected_slope[..., axis]
            np.subtract(cumulative[:, 1:, axis], cumulative[:, :-1, axis], out=slope[:, 1:])
            slope[:, 0] = cumulative[:, 0, axis]
    return hood


def _by_axis(shape: tuple[int, int, int]) -> np.ndarray:
    """An empty (K, m, 2) float64 array stored as (2, K, m): each axis's (K, m) is contiguous."""
    return np.empty((shape[2], shape[0], shape[1])).transpose(1, 2, 0)


def slope_levels(hood: Neighbourhoods, observed: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """(K, m) the pattern's pair level around each sloped point: its level windows' (:attr:`WindowScale.level`)
    cumulative tent counts over their expected counts (``observed``, ``expected``: (W, m) per-radius window sums of
    all families, :func:`synthesis.edgepcf_fast.window_sums`; :data:`LEVEL_PRIOR` pairs per point added to both),
    averaged over the point's windows with weights ``a_wc^2``; 1 outside every level window (and in a window of no weight).

    The expected counts' slope near borders and edges (``g grad D``) is scaled by this level, so it is ``g_hat grad D``
    for a pattern whose PCF is ``g_hat``: what the pair counts of such a pattern lose or gain along the same move. With
    the target's own ``g`` instead, any pattern short of the target's pairs (a clustered target early in the run, or
    held back by its leash) lowered its deficit by moving towards lower expected counts: points and whole clusters
    (their pairs move with them) gathered on the border and along correlation edges (red: 1.7-1.9 x the expected density
    in the border's first 0.5 r_max). A true sample (level 1) keeps the target's slope.
    """
    bounds = window_bounds(hood.windows)
    levels, total = np.zeros((len(hood.sloped), len(hood.radii))), np.zeros((len(hood.sloped), 1))
    for family, lo, hi in zip(hood.windows, bounds[:-1], bounds[1:]):
        if not family.scale.level:
            continue
        prior = LEVEL_PRIOR * window_totals(family.offsets, family.weights)[:, None]
        below = np.cumsum(expected[lo:hi], axis=1) + prior
        # a window whose members all weigh 0 (its centre's guide far from every member's) has no level: 1, not 0 / 0
        level = np.divide(np.cumsum(observed[lo:hi], axis=1) + prior, below, out=np.ones_like(below), where=below > 0)
        levels += sloped_window_sums(hood.sloped, hood.member_offsets, hood.member_window, hood.member_weight, lo, level)
        total += sloped_window_sums(hood.sloped, hood.member_offsets, hood.member_window, hood.member_weight, lo,
                                    np.ones((hi - lo, 1)))
    return np.where(total > 0, levels / np.maximum(total, 1e-300), 1.0)


def pair_slopes(hood: Neighbourhoods, points: np.ndarray, slopes: np.ndarray, slope_rows: np.ndarray,
                chunk: int = 1 << 20) -> np.ndarray:
    """(k, m) ``P_pj . slopes_pj`` for each of ``points`` (k,) int: P_pj (2,) the gradient of the pattern's guided
    cumulative tent counts at the anchors with respect to the point's position, ``d/dx_p sum_c C_c(j)`` over every
    centre c, so a point's pairs count twice, around itself (its own counts) and around each neighbour (their counts
    of it); ``C_c(j)`` = the tent counts of c's bins up to j, the objective's cumulative counts; ``slopes[slope_rows]``
    (k, m, 2) the directions it is projected on, per radius. Plain numpy, over the pair list in runs of ``chunk`` pairs
    (no (k, m, 2) or whole-list temporaries)."""
    xy, m = hood.anchor, len(hood.radii)
    row = np.full(len(xy), -1, np.int64)
    row[points] = np.arange(len(points))
    inv_width = 1.0 / (hood.radii[1] - hood.radii[0])
    out = np.zeros((len(points), m))
    for first in range(0, len(hood.neighbours), chunk):
        pairs = np.arange(first, min(first + chunk, len(hood.neighbours)))
        centres = np.searchsorted(hood.offsets, pairs, side="right") - 1
        neighbours = hood.neighbours[pairs].astype(np.int64)
        held = (row[centres] >= 0) | (row[neighbours] >= 0)
        pairs, centres, neighbours = pairs[held], centres[held], neighbours[held]
        offset = xy[neighbours] - xy[centres]
        distance = np.sqrt(offset[:, 0] ** 2 + offset[:, 1] ** 2)
        scale = inv_width / hood.spacing[centres]
        t = distance * scale
        keep = (t < m) & (distance > 0)
        # up to bin j a pair counts 1 - (t - j) for t in (j, j + 1), 1 nearer, 0 farther: d C(j) / dt = -1 there, so
        # d C_c(j) / d x_c = guide * scale * offset / distance, and minus that for the neighbour
        pairs, centres, neighbours, offset, bin_ = (pairs[keep], centres[keep], neighbours[keep], offset[keep],
                                                   np.floor(t[keep]).astype(np.int64))
        force = (hood.guide[pairs] * scale[keep] / distance[keep])[:, None] * offset
        for role, sign in ((centres, 1.0), (neighbours, -1.0)):
            at = row[role]
            mine = at >= 0
            at, j = at[mine], bin_[mine]
            along = slope_rows[at]
            projected = sign * (force[mine, 0] * slopes[along, j, 0] + force[mine, 1] * slopes[along, j, 1])
            np.add.at(out, (at, j), projected)
    return out


def edge_points(hood: Neighbourhoods) -> np.ndarray:
    """(K,) bool: the sloped points that lie at a correlation edge (a pair of theirs guided below :data:`EDGE_GUIDE`)."""
    lowest = np.ones(len(hood.spacing))
    listed = np.flatnonzero(np.diff(hood.offsets) > 0)
    lowest[listed] = np.minimum.reduceat(hood.guide, hood.offsets[listed])
    return lowest[hood.sloped] < EDGE_GUIDE


def edge_slope_levels(hood: Neighbourhoods, model: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """(K, m) the slope levels of the sloped points, with those at a correlation edge (:func:`edge_points`) moved
    :data:`EDGE_SLOPE_SHARE` x (1 - regularity) of the way from their pair level towards the ratio of the pattern's own
    pair-count derivative (:func:`pair_slopes`) to the model slope ``model`` (K, m, 2), ``g grad D`` cumulated over the
    radii.

    The objective's pair forces move a point by its own counts and by its neighbours' counts of it (each pair counts
    twice), while the expected counts' slope ``g grad D`` is its own count's only: for Poisson points the pairs'
    derivative is twice the slope. Wherever a window is short of pairs (a clustered target while its clusters form,
    level 0.3-0.4 at the second refresh) the pairs then pull points off the edge harder than the slope holds them:
    red's side of a red | blue edge thinned to 0.77 of the expected density 0.5-1 r_max from it (12 seeds) and
    gathered 2-3 r_max inside, while a true sample run through the same objective keeps its edge. The ratio per level
    window (:attr:`WindowScale.level`) and radius is the least-squares fit ``sum a^2 P.M / sum a^2 M.M`` over its edge
    points (P the pair derivative, M the model slope), clipped to [0, :data:`EDGE_SLOPE_MAX`], averaged over each
    point's windows with weights ``a_wc^2`` as :func:`slope_levels` averages levels. The whole ratio (share 1) put red
    at 0.88-1.23 but green's strip at 0.5-1 r_max at 1.28, the minimum its objective keeps from a true sample
    (1.20-1.23); half: red 0.84-1.09, green 0.86-1.21 (docs/synthesis.md, "Border and edge strips"). Regular targets
    keep their level (a regular start already holds their pairs, and the tone term their edges): with the share,
    blue's side of a lattice | blue edge piled to 1.28 (1.24 before).
    """
    edge = edge_points(hood)
    if not edge.any():
        return levels
    points = hood.sloped[edge]
    rows = np.flatnonzero(edge)
    fit, norm = pair_slopes(hood, points, model, rows), model[rows, :, 0] ** 2 + model[rows, :, 1] ** 2  # (k, m)
    row = np.full(len(hood.spacing), -1, np.int64)
    row[points] = np.arange(len(points))
    bounds = window_bounds(hood.windows)
    ratio, total = np.zeros((len(points), len(hood.radii))), np.zeros((len(points), len(hood.radii)))
    for family, lo, hi in zip(hood.windows, bounds[:-1], bounds[1:]):
        if not family.scale.level:
            continue
        member = row[family.members]
        held = member >= 0
        windows, first = np.unique(family.owners[held], return_index=True)  # owners ascend: each window's run of rows
        if not len(windows):
            continue
        weight, member = family.weights[held].astype(np.float64) ** 2, member[held]
        sums = np.empty((2, len(windows), len(hood.radii)))
        for j in range(len(hood.radii)):  # a radius at a time: no (members, m) temporaries
            sums[0, :, j] = np.add.reduceat(weight * fit[member, j], first)
            sums[1, :, j] = np.add.reduceat(weight * norm[member, j], first)
        known, window_ratio = np.zeros((hi - lo, len(hood.radii))), np.zeros((hi - lo, len(hood.radii)))
        known[windows] = sums[1] > 0  # a window whose edge points have no slope at a radius measures nothing there
        window_ratio[windows] = np.clip(sums[0] / np.maximum(sums[1], 1e-300), 0.0, EDGE_SLOPE_MAX) * known[windows]
        ratio += sloped_window_sums(points, hood.member_offsets, hood.member_window, hood.member_weight, lo, window_ratio)
        total += sloped_window_sums(points, hood.member_offsets, hood.member_window, hood.member_weight, lo, known)
    out = levels.copy()
    fitted = np.where(total > 0, ratio / np.maximum(total, 1e-300), levels[rows])
    out[rows] += (EDGE_SLOPE_SHARE * (1.0 - hood.regularity[points]))[:, None] * (fitted - levels[rows])
    return out


def _variance_force(windows: list[Windows], members: tuple[np.ndarray, np.ndarray, np.ndarray], sloped: np.ndarray,
                    variance_slope: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(K, 2) gradient of the quadratic windows' variance compensation at the sloped points.

    A quadratic window loss has expectation ``bias^2 + Var(r)`` even at a true
    sample, and ``Var(r)`` grows with the window's expected counts: without
    compensation the optimiser lowers variance by moving points to where they
    expect fewer neighbours (onto borders and edges). The objective therefore
    subtracts the model variance ``sum_c a_wc^2 f_j V_c(x_c)`` (f_j from
    :data:`CUMULATIVE_VARIANCE`, V_c the point's count variance: dispersion x
    (expected cumulative count + 1)) of each quadratic window over its
    deviation^2; it depends on positions only through the sloped points'
    expected counts, ``variance_slope`` (K, m, 2) = dispersion x grad K.
    ``members``: the point lists of :func:`synthesis.edgepcf_fast.point_lists`.
    """
    force = np.zeros((len(sloped), 2))
    if not len(sloped):
        return force
    width = radii[1] - radii[0]
    model = CUMULATIVE_VARIANCE[0] + CUMULATIVE_VARIANCE[1] * (radii + width)
    for family, first in zip(windows, window_bounds(windows)):
        if not family.scale.compensation:
            continue
        scale = family.scale.compensation * family.scale.weight / family.deviation.size
        per_point = sloped_window_sums(sloped, *members, first, model / family.deviation.astype(np.float64) ** 2)
        force -= scale * np.einsum("kj,kjd->kd", per_point, variance_slope)
    return force


def regularity(target: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(...) in [0, 1]: how far the target PCF (..., m) stays below 1 at short range (1 = hard core, 0 = Poisson or clustered)."""
    short = radii <= REGULAR_RANGE
    return np.clip(1.0 - target[..., short].mean(axis=-1), 0.0, 1.0)


def regularity_at(fields: MapFields, xy: np.ndarray) -> np.ndarray:
    """(n,) :func:`regularity` of the map's target at positions xy (n, 2): the same values, sampling only the radii it
    reads (a quarter of the target's 52: the start and the tone term sample it at 100k points or cells each), the mean
    taken in float64."""
    short = fields.radii <= REGULAR_RANGE
    samples = sample_table(fields.target_table[:, short], fields.colour, xy, fields.side_px).astype(np.float64)
    return regularity(samples, fields.radii[short])


def spread_clusters(target: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(...) in [0, 1]: how far the target PCF (..., m) is clustered with its clusters spread regularly (green: 1; red,
    Matern, white, blue, step: 0): its short-range PCF above 1 (:data:`REGULAR_RANGE`) and a trough between its clusters,
    its minimum over :data:`TROUGH_RANGE`, below :data:`TROUGH_LEVEL` (full at ``TROUGH_LEVEL - TROUGH_DEPTH``)."""
    short, between = radii <= REGULAR_RANGE, (radii >= TROUGH_RANGE[0]) & (radii <= TROUGH_RANGE[1])
    clustered = np.clip(target[..., short].mean(axis=-1) - 1.0, 0.0, 1.0)
    return clustered * np.clip((TROUGH_LEVEL - target[..., between].min(axis=-1)) / TROUGH_DEPTH, 0.0, 1.0)


def spread_clusters_at(fields: MapFields, xy: np.ndarray) -> np.ndarray:
    """(n,) :func:`spread_clusters` of the target of the field pixel under each position xy (n, 2) (its colour's, not a
    bilinear blend: between red and blue pixels a blend has clusters and a trough, and neither side has both)."""
    colour = fields.colour[pixels_of(xy, fields.colour.shape, fields.side_px)]
    return spread_clusters(fields.target_table.astype(np.float64), fields.radii)[colour]


def structure(target: np.ndarray) -> np.ndarray:
    """(...) in [0, 1]: how far the target PCF (..., m) departs from 1 anywhere (0 within :data:`POISSON_TOLERANCE`).

    A white-noise target is what the independent start already is: its points need not move.
    """
    furthest = np.maximum(target.max(axis=-1) - 1.0, 1.0 - target.min(axis=-1))  # max |g - 1| without a temporary
    return np.clip((furthest - POISSON_TOLERANCE) / STRUCTURE_RANGE, 0.0, 1.0)


def dead_zone(x: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Penalty ``max(|x| - width, 0)^2`` and its derivative, elementwise on standardised deviations x."""
    excess = np.maximum(np.abs(x) - width, 0.0)
    return excess**2, 2.0 * np.sign(x) * excess


def expected_counts(xy: np.ndarray, hood: Neighbourhoods) -> np.ndarray:
    """(n, m) target tent counts at positions xy (n, 2), linearised around the refresh's positions."""
    expected = hood.expected()
    expected[hood.sloped] += np.einsum("kjd,kd->kj", hood.expected_slope, xy[hood.sloped] - hood.anchor[hood.sloped])
    return expected


def pair_counts_reference(xy: np.ndarray, hood: Neighbourhoods) -> np.ndarray:
    """Guided tent counts S (n, m) around every point (plain numpy)."""
    n, m = len(xy), len(hood.radii)
    centres = hood.centres
    width = hood.radii[1] - hood.radii[0]
    t = np.linalg.norm(xy[hood.neighbours] - xy[centres], axis=1) / (hood.spacing[centres] * width)
    counts = np.zeros((n, m + 1))
    keep = t < m
    lower = np.floor(t[keep]).astype(np.int64)
    frac = t[keep] - lower
    np.add.at(counts, (centres[keep], lower), hood.guide[keep] * (1 - frac))
    np.add.at(counts, (centres[keep], lower + 1), hood.guide[keep] * frac)
    return counts[:, :m]


def objective_reference(xy: np.ndarray, hood: Neighbourhoods, gradient: bool = True) -> tuple[float, np.ndarray | None]:
    """Objective L (see the module docstring) and its gradient (n, 2) w.r.t. xy (n, 2); plain numpy."""
    xy = np.asarray(xy, np.float64)
    n, m = len(xy), len(hood.radii)
    excess = pair_counts_reference(xy, hood) - expected_counts(xy, hood)
    cumulative = np.cumsum(excess, axis=1)
    loss, back_cumulative = 0.0, np.zeros((n, m))
    for windows in hood.windows:
        scale = windows.scale.weight / ((len(windows.offsets) - 1) * m)
        standardised = windows.aggregate(cumulative) / windows.deviation
        penalty, slope = dead_zone(standardised, windows.scale.dead_zone)
        loss += float(penalty.sum()) * scale
        back_cumulative += windows.distribute(slope / windows.deviation * scale, n)  # dL/dK (cumulative counts)
    loss += float(np.sum(hood.variance_force * (xy[hood.sloped] - hood.anchor[hood.sloped])))
    if not gradient:
        return loss, None
    back = np.cumsum(back_cumulative[:, ::-1], axis=1)[:, ::-1]  # dL/dS = -dL/dE
    back = np.concatenate([back, np.zeros((n, 1))], axis=1)
    centres = hood.centres
    width = hood.radii[1] - hood.radii[0]
    offset = xy[hood.neighbours] - xy[centres]
    distance = np.linalg.norm(offset, axis=1)
    scale = 1.0 / (hood.spacing[centres] * width)
    t = distance * scale
    keep = (t < m) & (distance > 0)
    lower = np.floor(t[keep]).astype(np.int64)
    pull = hood.guide[keep] * (back[centres[keep], lower + 1] - back[centres[keep], lower])  # dL/dt
    force = (pull * scale[keep] / distance[keep])[:, None] * offset[keep]  # dL/dx_neighbour
    grad = np.zeros((n, 2))
    np.add.at(grad, hood.neighbours[keep], force)
    np.add.at(grad, centres[keep], -force)
    grad[hood.sloped] -= np.einsum("kj,kjd->kd", back[hood.sloped, :m], hood.expected_slope)
    grad[hood.sloped] += hood.variance_force
    return loss, grad


def estimate(xy: np.ndarray, hood: Neighbourhoods, denominator: np.ndarray) -> np.ndarray:
    """Edge-aware PCF (n, m) around every point: tent counts / the Poisson ``denominator`` (n, m)."""
    return pair_counts_reference(np.asarray(xy, np.float64), hood) / denominator


def local_errors(lab_map: LabMap, points: np.ndarray, n: int | None = None,
                 palette: Palette | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(W,) mean-over-radii |window PCF - window target| per aggregation window of a pattern (n, 2), and the
    windows' centres (W, 2) (their members' weighted mean positions, map units).

    The map's target PCFs come from ``palette`` (default: the shipped one); ``n``
    sets the map's point spacing (default: the pattern's own count). Windows without points (where the map
    has ink and the pattern none) have no PCF and are left out.
    """
    from synthesis.palette import load_palette

    fields = MapFields.build(lab_map, len(points) if n is None else n, palette or load_palette())
    points = np.asarray(points, np.float64)
    hood = find_neighbourhoods(fields, points)
    windows = hood.windows[0]
    poisson = windows.aggregate(fields.denominator_at(points))
    populated = np.all(poisson > 0, axis=1)  # windows without points: no PCF (0 / 0)
    poisson = poisson[populated]
    observed = windows.aggregate(pair_counts_reference(points, hood))[populated] / poisson
    target = windows.aggregate(hood.expected())[populated] / poisson
    sums = windows.aggregate(np.concatenate([points, np.ones((len(points), 1))], axis=1))[populated]  # (W, 3): weighted x, y, weight
    centres = sums[:, :2] / np.maximum(sums[:, 2:], 1e-300)
    return np.abs(observed - target).mean(axis=1), centres
