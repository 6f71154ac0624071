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
pair-count excess ``e(c, j) = S(c, j) - g(c, j) D(c, j)`` is summed over a
guided window of centres, ``r = A^P e`` with ``A = I + W``,
``W[w, c] = taper(|x_c - x_w| / (R s(w))) H(z_c, z_w)`` for the window's
neighbours (radius R = :data:`WINDOW_RADIUS` spacings; P = :data:`WINDOW_PASSES`
passes widen it), and scored like a chi-square against the Poisson variance of
the same window, ``V = A^P D``:

    L = sum_{w, j} r(w, j)^2 / V(w, j) / (n m)

A true sample of the target scores about 1 per bin whatever its natural
variation; stacked or too-close pairs fall in the small-radius bins where the
target expects none, and cost. The gradient is written out by hand (chain rule
through the pair distances; window weights, fields and H are held fixed between
neighbour refreshes), so memory stays O(pairs).

Two implementations: :func:`objective_reference` (plain numpy, the reference
the tests compare against) and the fused numba kernels of
:mod:`synthesis.edgepcf_fast`, used by the synthesiser.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from synthesis.fields import MapFields, guide_similarity
from synthesis.labmap import LabMap
from synthesis.palette import Palette
from synthesis.pcf import neighbour_cutoff, neighbours_within
from synthesis.stratified import StratifiedSampler

CUMULATIVE_VARIANCE = (1.0, 5.0)  # Var / (sum a^2 K) of a window's cumulative count at radius rho: 1 + 5 rho (Poisson, measured)
BIN_VARIANCE = 1.3  # Var / (sum a^2 S) of a window's count per radius (Poisson, measured: each pair in two counts, tent^2)
REGULAR_RANGE = 0.55  # radii (units of r_max) over which the target's short-range PCF measures its regularity
VARIANCE_FLOOR = 0.05  # pairs^2: one stray pair where the target expects none is 4.5 standard deviations


@dataclass(frozen=True)
class WindowScale:
    """One family of aggregation windows and how its deviations are scored.

    Attributes:
        radius: window radius in units of the spacing at the window's centre.
        points_per_window: windows per refresh = n / this (windows overlap: radius^2 > this).
        dead_zone: standardised deviations within this many standard deviations cost nothing.
        weight: the family's weight in the objective.
        cumulative: score cumulative counts (pairs closer than each radius: every step
            out of a hard core pays) instead of the counts per radius (the PCF's shape).
    """

    radius: float
    points_per_window: float
    dead_zone: float
    weight: float
    cumulative: bool


# Local windows (~40 points) catch outliers (holes, stacks, broken hard cores) and leave a true
# sample's natural variation alone; regional windows (~230 points) match the PCF's mean shape.
WINDOW_SCALES = (WindowScale(radius=3.3, points_per_window=8.0, dead_zone=2.0, weight=1.0, cumulative=True),
                 WindowScale(radius=8.0, points_per_window=48.0, dead_zone=0.0, weight=1.0, cumulative=True))


@dataclass
class Windows:
    """Aggregation windows of one scale (membership lists and their transpose).

    Attributes:
        scale: the :class:`WindowScale`.
        offsets: (W + 1,) int64; members of window w are ``offsets[w]:offsets[w + 1]`` ...
        members: (M,) int32 ... these points ...
        weights: (M,) float64 ... with these weights (taper x guide).
        by_member: (M,) int64 entries sorted by point (the transposed lists) ...
        member_offsets: (n + 1,) int64 ... with these offsets per point.
        deviation: (W, m) standard deviation of each window's cumulative count (Poisson model).
    """

    scale: WindowScale
    offsets: np.ndarray
    members: np.ndarray
    weights: np.ndarray
    by_member: np.ndarray
    member_offsets: np.ndarray
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
        guide: (P,) float64 guidance weights H of the pairs.
        by_neighbour: (P,) int64 pair indices sorted by neighbour (the transposed pair lists) ...
        neighbour_offsets: (n + 1,) int64 ... with these offsets per neighbour.
        spacing: (n,) local r_max at the points.
        expected: (n, m) target tent counts ``g D`` around each point.
        windows: one :class:`Windows` per :data:`WINDOW_SCALES` entry.
        radii: (m,) radii in units of r_max.
        regularity: (n,) in [0, 1], how far the target PCF at each point stays below 1 at short range.
    """

    offsets: np.ndarray
    neighbours: np.ndarray
    guide: np.ndarray
    by_neighbour: np.ndarray
    neighbour_offsets: np.ndarray
    spacing: np.ndarray
    expected: np.ndarray
    windows: list[Windows]
    radii: np.ndarray
    regularity: np.ndarray

    @property
    def centres(self) -> np.ndarray:
        """(P,) centre of each pair."""
        return _owners(self.offsets)


def _owners(offsets: np.ndarray) -> np.ndarray:
    return np.repeat(np.arange(len(offsets) - 1), np.diff(offsets)).astype(np.int32)


def window_taper(u: np.ndarray) -> np.ndarray:
    """Smooth window weight ``(1 - u^2)^2`` for distances u < 1 in units of the window radius, else 0."""
    q = np.clip(1.0 - np.asarray(u) ** 2, 0.0, None)
    return q * q


def window_squares(values: np.ndarray, windows: Windows) -> np.ndarray:
    """(W, m) ``sum_c a_wc^2 values_c`` for per-point values (n, m)."""
    from synthesis.edgepcf_fast import window_sums

    return window_sums(values, windows.offsets, windows.members, windows.weights**2)


def _csr(index: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row offsets (R + 1,) and flat entries of a padded (R, K) index array where ``valid``."""
    offsets = np.zeros(len(index) + 1, np.int64)
    np.cumsum(valid.sum(axis=1), out=offsets[1:])
    return offsets, index[valid].astype(np.int32)


def _transpose(entries: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Entry order sorted by target (M,) and offsets (count + 1,) per target of a flat list of targets."""
    order = np.argsort(entries, kind="stable")
    offsets = np.zeros(count + 1, np.int64)
    np.cumsum(np.bincount(entries, minlength=count), out=offsets[1:])
    return order, offsets


class WindowSampler:
    """Window centres for every scale, stratified with the map's intensity (independent of any pattern)."""

    def __init__(self, fields: MapFields):
        self.n = fields.n
        self.sampler = StratifiedSampler(fields.intensity[..., 0], fields.side_px, fields.domain, fields.n)

    def draw(self, rng: np.random.Generator) -> list[np.ndarray]:
        """One (W, 2) array of centres per :data:`WINDOW_SCALES` entry."""
        return [self.sampler.draw(max(1, round(self.n / scale.points_per_window)), rng) for scale in WINDOW_SCALES]


def _windows(scale: WindowScale, fields: MapFields, tree: cKDTree, latent: np.ndarray, expected: np.ndarray,
             centres: np.ndarray) -> Windows:
    n = tree.n
    at = fields.at(centres)
    reach = scale.radius * at["spacing"].astype(np.float64)
    distance, index = neighbours_within(tree, centres, reach)
    valid = index < n
    offsets, members = _csr(index, valid)
    owners = _owners(offsets)
    weights = window_taper(distance[valid] / reach[owners])
    if fields.guide:
        weights = weights * guide_similarity(latent[members], at["latent"].astype(np.float64)[owners])
    by_member, member_offsets = _transpose(members, n)
    windows = Windows(scale, offsets, members, weights, by_member, member_offsets, np.empty(0))
    if scale.cumulative:
        squared = window_squares(np.cumsum(expected, axis=1), windows)
        factor = CUMULATIVE_VARIANCE[0] + (CUMULATIVE_VARIANCE[1] if scale.dead_zone else 0.0) * (fields.radii + (fields.radii[1] - fields.radii[0]))
    else:
        squared = window_squares(expected, windows)
        factor = BIN_VARIANCE
    windows.deviation = np.sqrt(factor * squared + VARIANCE_FLOOR)
    return windows


def find_neighbourhoods(fields: MapFields, xy: np.ndarray, window_centres: list[np.ndarray] | None = None) -> Neighbourhoods:
    """Every pair within the estimator's reach (cutoff x spacing of the centre), windows, and the fields at the points.

    ``window_centres``: one (W, 2) array per :data:`WINDOW_SCALES` entry, where the
    windows sit; they must not depend on the pattern (default: a fixed-seed
    :class:`WindowSampler` draw; the synthesiser draws new ones at every refresh).
    """
    xy = np.asarray(xy, np.float64)
    n = len(xy)
    if window_centres is None:
        window_centres = WindowSampler(fields).draw(np.random.default_rng(0))
    at = fields.at(xy)
    spacing = at["spacing"].astype(np.float64)
    latent = at["latent"].astype(np.float64)
    tree = cKDTree(xy)
    _, index = neighbours_within(tree, xy, neighbour_cutoff(fields.radii) * spacing)
    offsets, neighbours = _csr(index, (index < n) & (index != np.arange(n)[:, None]))
    centres = _owners(offsets)
    guide = guide_similarity(latent[neighbours], latent[centres]) if fields.guide else np.ones(len(neighbours))
    expected = at["target"].astype(np.float64) * at["denominator"]
    windows = [_windows(scale, fields, tree, latent, expected, where) for scale, where in zip(WINDOW_SCALES, window_centres)]
    by_neighbour, neighbour_offsets = _transpose(neighbours, n)
    return Neighbourhoods(offsets, neighbours, guide, by_neighbour, neighbour_offsets, spacing, expected, windows,
                          np.asarray(fields.radii, np.float64), regularity(at["target"], fields.radii))


def regularity(target: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(...) in [0, 1]: how far the target PCF (..., m) stays below 1 at short range (1 = hard core, 0 = Poisson or clustered)."""
    short = radii <= REGULAR_RANGE
    return np.clip(1.0 - target[..., short].mean(axis=-1), 0.0, 1.0)


def dead_zone(x: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Penalty ``max(|x| - width, 0)^2`` and its derivative, elementwise on standardised deviations x."""
    excess = np.maximum(np.abs(x) - width, 0.0)
    return excess**2, 2.0 * np.sign(x) * excess


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
    excess = pair_counts_reference(xy, hood) - hood.expected
    cumulative = np.cumsum(excess, axis=1)
    loss, back, back_cumulative = 0.0, np.zeros((n, m)), np.zeros((n, m))
    for windows in hood.windows:
        scale = windows.scale.weight / ((len(windows.offsets) - 1) * m)
        standardised = windows.aggregate(cumulative if windows.scale.cumulative else excess) / windows.deviation
        penalty, slope = dead_zone(standardised, windows.scale.dead_zone)
        loss += float(penalty.sum()) * scale
        part = windows.distribute(slope / windows.deviation * scale, n)
        if windows.scale.cumulative:
            back_cumulative += part  # dL/dK (cumulative counts)
        else:
            back += part
    if not gradient:
        return loss, None
    back += np.cumsum(back_cumulative[:, ::-1], axis=1)[:, ::-1]  # dL/dS
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
    return loss, grad


def estimate(xy: np.ndarray, hood: Neighbourhoods, denominator: np.ndarray) -> np.ndarray:
    """Edge-aware PCF (n, m) around every point: tent counts / the Poisson ``denominator`` (n, m)."""
    return pair_counts_reference(np.asarray(xy, np.float64), hood) / denominator


def local_errors(lab_map: LabMap, points: np.ndarray, n: int | None = None,
                 palette: Palette | None = None) -> tuple[np.ndarray, MapFields]:
    """(W,) mean-over-radii |window PCF - window target| per aggregation window of a pattern (n, 2), and the fields.

    The map's target PCFs come from ``palette`` (default: the shipped one); ``n``
    sets the map's point spacing (default: the pattern's own count).
    """
    from synthesis.palette import load_palette

    fields = MapFields.build(lab_map, len(points) if n is None else n, palette or load_palette())
    points = np.asarray(points, np.float64)
    hood = find_neighbourhoods(fields, points)
    windows = hood.windows[0]
    poisson = windows.aggregate(fields.at(points)["denominator"])
    observed = windows.aggregate(pair_counts_reference(points, hood)) / poisson
    target = windows.aggregate(hood.expected) / poisson
    return np.abs(observed - target).mean(axis=1), fields
