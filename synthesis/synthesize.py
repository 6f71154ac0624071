"""Synthesis: a point pattern whose edge-aware PCF matches a map's target everywhere (paper §6).

**Start.** Density-matched points (:mod:`synthesis.stratified`): stratified
along a Hilbert curve where the target is regular (its PCF below 1 at short
range: blue, step, jitter), independent where it is not (white, green,
clustered), mixed in proportion in between; so a blue region starts with no
holes and a white one starts as a true Poisson sample.

**Optimisation.** Momentum descent on the window objective of
:mod:`synthesis.edgepcf` (fused numba kernels), every point a centre at every
iteration: Adam's first moment per point, its second moment shared by all
points, so a point with a small, consistent gradient (a white-noise region, a
slight bias) moves little instead of a full step. Steps are per point and
measured in units of the local spacing r_max(x), so dense and sparse regions
converge alike; they decay from ``step`` to ``final_step`` along a cosine, are
``free_step`` times longer where the target is not regular (clusters must
form from an independent start) and shrink to 0 where the target is white
noise (the independent start already is a true sample; where that is every
point, the run stops at once). Pair lists, windows
and the fields at the points are refreshed every ``refresh`` iterations at
the initial step, less often as the step decays (whenever the points could
have moved as far as in ``refresh`` initial steps: 5 refreshes in 180
iterations; the leash bounds what a stale pair list can miss).
Points leaving the domain are mirrored back in, momentum reversed (a border is
a mirror, not a wall that collects points); so are points landing where the
map has no ink, at the edge of the nearest inked pixel
(:func:`hold_in_ink_reference`): the start is drawn on ink, but nothing else
keeps a point there, and next to white its neighbours all lie on one side.
Every point stays within a leash
of ``leash`` local spacings (``x free_step`` where the target is not regular)
of its start: the start matches the density at every scale (stratified), and
the leash stops the local rearrangement that makes the texture from turning
into a drift that loses it (camera, 20k points, density PSNR at a blur of 2
spacings: 35.9 dB at the start, 27.1 dB after 250 unleashed iterations,
32.0 dB with the leash; the weighted Lloyd stippler 32.1 dB).

**Tone.** The PCF objective sees pair counts relative to the local density,
not the density: alone, it let the tone drift (camera, 5k points, density
PSNR at a blur of 4 spacings: 48.8 dB at the start, 34.0 dB after the run).
The tone term of :mod:`synthesis.density_term` (weight ``tone``, blur
``tone_scale`` = 3 mean spacings, only where the target is regular) holds the
points' density blurred at that scale to the map's: camera at 20k points,
31.6 -> 48.8 dB at a blur of 2 spacings (weighted Lloyd 32.3, CCVT 45.0),
with the constant-map statistics of blue unchanged (a blur of 1-1.5 spacings
made blue more regular than its generator: fine-PCF ratio 1.4-2.4).

**Warm start.** ``start_points`` replaces the density-matched start (an edit: :func:`redrawn_start` keeps a
previous result outside the edited region and re-draws inside); the run is the same schedule: a re-drawn region is a
fresh start and needs all of it (measured), while converged points barely move.

One schedule, ``fast`` (:data:`SCHEDULES`: 180 iterations, steps 0.1 -> 0.01
spacings, refresh 20, free_step 3, leash 0.7 spacings, tone 1e4 at 3 spacings). Unlike the paper's 5,000 iterations
on jittered Monte-Carlo centres, every point is a centre at every iteration. It was 250 iterations of 0.05 -> 0.01
refreshed every 10 (15 refreshes); the constant maps (4,096 points, 3 seeds) and the camera's tone (5,000 points)
measured the same with 150 of 0.1 until the start's strata were jittered; with that start 150 lost blue's hard
core and 180 keeps it (docs/synthesis.md, "Schedule measurements"): 0.72 of the iterations, a third of the refreshes.
"""

from __future__ import annotations

import contextlib
import gc
import math
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from synthesis.conventions import POINTS_PER_INK, full_ink_points
from synthesis.errors import PatternshopError, PatternshopWarning
from synthesis.fields import DenominatorTracker, MapFields
from synthesis.labmap import LabMap, pixels_of
from synthesis.palette import Palette, load_palette
from synthesis.points import PointSet
from synthesis.workspace import Workspace

if TYPE_CHECKING:
    from synthesis.edgepcf import WindowSampler


@dataclass(frozen=True)
class Schedule:
    """How the optimisation runs (see the module docstring)."""

    name: str
    iterations: int
    refresh: float  # iterations between refreshes at the initial step; the interval grows as the step decays
    step: float  # initial step, in units of the local spacing, where the target is regular (a hard core)
    final_step: float
    free_step: float  # step factor where the target is not regular (Poisson, clustered): points travel further
    leash: float  # how far a point may move from its start, in local spacings (x free_step where not regular)
    tone: float = 0.0  # weight of the tone term (synthesis.density_term; 0: none)
    tone_scale: float = 1.0  # its blur, in mean spacings sqrt(A / n)
    neighbours: float = 0.0  # weight of the nearest-neighbour term (synthesis.neighbour_term; 0: none)

    def rate(self, step: int, iterations: int) -> float:
        """The step (local spacings) of iteration ``step`` of ``iterations``: a cosine from ``step`` to ``final_step``."""
        fraction = step / max(iterations - 1, 1)
        return self.final_step + 0.5 * (self.step - self.final_step) * (1 + math.cos(math.pi * fraction))


BORDER_STEP_BAND = 5.0  # spacings from the domain's border: the pairs' reach (2.8) and a refresh's travel (1.7, p99)
SCHEDULES = {"fast": Schedule("fast", iterations=180, refresh=20, step=0.1, final_step=0.01, free_step=3.0, leash=0.7,
                              tone=1e4, tone_scale=3.0, neighbours=1e3)}
# A run's figures are absurd (sound runs measured: constant, random, disc, text, line and 1 x 10000 maps, every preset):
ABSURD_LOSS_GROWTH = 100.0  # a final loss this many times its start's (sound runs: at most 2.2x) ...
LOSS_NOISE = 10.0  # ... or than this, whichever is larger (dead zones: a sound start can score 1.7e-5, its end 0.66)
ABSURD_MISPLACED = 0.7  # points to move to match the density on coarse cells (sound runs: at most 0.16, clustered red;
# all in one cell: 1 - 1 / cells, 0.875 for the 1 x 10000 map before its start was fixed; its density SSIM, 0.001, is
# no test: a sound constant red map scores 0.04)
CELL_POINTS = 25  # expected points per coarse cell of a uniform square map, at least (Poisson noise ~ 1 / 5)


@dataclass
class SynthesisResult:
    """Points and a record of the run (``report()`` gives the JSON-ready summary)."""

    points: PointSet
    schedule: str
    iterations: int
    seconds: float
    setup_seconds: float
    losses: list[float] = field(default_factory=list)
    final_loss: float = math.nan
    warnings: list[str] = field(default_factory=list)  # what :func:`absurd_run` found (also warned)

    def report(self) -> dict:
        return {"n": len(self.points), "schedule": self.schedule, "iterations": self.iterations,
                "seconds": round(self.seconds, 3), "setup_seconds": round(self.setup_seconds, 3),
                "final_loss": self.final_loss, "domain": list(self.points.domain), "warnings": list(self.warnings)}


def misplaced_share(lab_map: LabMap, xy: np.ndarray) -> float:
    """Share in [0, 1] of the points (n, 2) that would have to move for their counts on coarse cells to follow the
    map's density (total variation distance). Cells are squares of 1/k of the longer side, ``k = sqrt(n / 25)``
    clamped to 1..8 (:data:`CELL_POINTS`), so even a sound clustered sample stays well below :data:`ABSURD_MISPLACED`.
    """
    side = max(lab_map.width, lab_map.height)
    k = min(8, max(1, math.isqrt(len(xy) // CELL_POINTS)))

    def cells(size: int) -> np.ndarray:  # (k, size) float32: which cell each pixel of a row or column falls in
        return (((np.arange(size) + 0.5) * k // side)[None, :] == np.arange(k)[:, None]).astype(np.float32)

    expected = (cells(lab_map.height) @ lab_map.density() @ cells(lab_map.width).T).reshape(-1).astype(np.float64)
    cell = np.clip((np.asarray(xy) * k).astype(np.int64), 0, k - 1)
    observed = np.bincount(cell[:, 1] * k + cell[:, 0], minlength=k * k)
    return 0.5 * float(np.abs(observed / len(xy) - expected / expected.sum()).sum())


def absurd_run(start_loss: float, final: float, misplaced: float) -> list[str]:
    """One message per figure no sound run gives (see :data:`ABSURD_LOSS_GROWTH`), each also warned as a
    :class:`PatternshopWarning`: a final loss that is not finite or at least :data:`ABSURD_LOSS_GROWTH` x
    max(``start_loss``, :data:`LOSS_NOISE`); a :func:`misplaced_share` of at least :data:`ABSURD_MISPLACED`.
    """
    messages = []
    if not (math.isfinite(final) and final < ABSURD_LOSS_GROWTH * max(start_loss, LOSS_NOISE)):
        messages.append(f"the synthesis failed: its final loss {final:.3g} is over {ABSURD_LOSS_GROWTH:g} x its "
                        f"start's {start_loss:.3g}")
    if not misplaced < ABSURD_MISPLACED:
        messages.append(f"the synthesis failed: {misplaced:.0%} of the points would have to move to follow the "
                        "map's density")
    for message in messages:
        warnings.warn(message, PatternshopWarning, stacklevel=2)
    return messages


def point_count(lab_map: LabMap, points_per_ink: float = POINTS_PER_INK) -> int:
    """``round(points_per_ink x w x h x mean(1 - L/100))``, ``points_per_ink`` per unit area of full ink
    (:data:`synthesis.conventions.POINTS_PER_INK_MEANING`); an all-white map is an error."""
    n = int(round(full_ink_points(points_per_ink, lab_map.domain) * float(lab_map.density().mean())))
    if n < 1:
        raise PatternshopError("the map is white everywhere (no ink): there is nothing to place points on")
    return n


def points_per_ink_of(lab_map: LabMap, n: int) -> float:
    """The points per unit area of full ink at which ``lab_map`` holds ``n`` points (:func:`point_count`'s inverse)."""
    return n / full_ink_points(1.0, lab_map.domain) / max(float(lab_map.density().mean()), 1e-12)


def initial_points(lab_map: LabMap, n: int, rng: np.random.Generator, fields: MapFields | None = None) -> np.ndarray:
    """(n, 2) density-matched start: stratified where the target is regular, independent elsewhere.

    Without ``fields`` (no target known) the start is independent (inhomogeneous Poisson).
    """
    from synthesis.edgepcf import regularity_at
    from synthesis.stratified import StratifiedSampler, random_points

    density = lab_map.density().astype(np.float64)
    side_px, domain = max(lab_map.width, lab_map.height), lab_map.domain
    independent = random_points(density, side_px, domain, n, rng)
    if fields is None:
        return independent
    stratified = StratifiedSampler(density, side_px, domain, n, rng).draw(n, rng)  # a random extent: no lattice
    regular_s, regular_i = regularity_at(fields, stratified), regularity_at(fields, independent)
    chosen = np.concatenate([stratified[rng.random(n) < regular_s], independent[rng.random(n) >= regular_i]])
    if len(chosen) > n:
        return chosen[np.sort(rng.choice(len(chosen), n, replace=False))]
    if len(chosen) < n:  # top up from an independent draw (rare: the two shares fluctuate)
        chosen = np.concatenate([chosen, random_points(density, side_px, domain, n - len(chosen), rng)])
    return chosen


def redrawn_start(lab_map: LabMap, xy: np.ndarray, region: np.ndarray, seed: int = 0, n: int | None = None,
                  palette: Palette | None = None) -> np.ndarray:
    """A warm start (k, 2) for ``synthesize(lab_map, start_points=...)`` after an edit: the points xy (m, 2) of a
    previous result outside ``region`` ((H, W) on the map's pixels, > 0.5 where edited), then the edited map's own
    density-matched start (:func:`initial_points`, stratified where the target is regular) inside it.

    ``n``: the total the new start is drawn for (default: the kept points' count over the share of the map's ink
    outside the region, so the points per ink stay; required if the region holds all the ink). Re-draw this way, not
    with independent points: a warm start moves points at most a leash of 0.7 spacings (blue), too little to mend an
    independent sample's holes and clumps.
    """
    mask = np.asarray(region) > 0.5
    if mask.shape != (lab_map.height, lab_map.width):
        raise PatternshopError(f"region is {mask.shape[::-1]} pixels, the map {lab_map.width} x {lab_map.height}")
    xy = checked_start_points(xy, None, lab_map.domain) if len(xy) else np.zeros((0, 2))

    def edited(points: np.ndarray) -> np.ndarray:
        return mask[pixels_of(points, mask.shape)]

    kept = xy[~edited(xy)]
    density = lab_map.density()
    outside = float(density[~mask].sum()) / max(float(density.sum()), 1e-30)
    if n is None:
        if not len(kept) or outside <= 0.0:
            raise PatternshopError("the region holds all the map's ink (or no point is kept): give n")
        n = max(2, round(len(kept) / outside))
    fresh = initial_points(lab_map, n, np.random.default_rng(seed), MapFields.build(lab_map, n, palette or load_palette()))
    return np.concatenate([kept, fresh[edited(fresh)]])


def checked_start_points(start_points: np.ndarray, n: int | None, domain: tuple[float, float]) -> np.ndarray:
    """A warm start as a fresh (k, 2) float64 array, or a :class:`PatternshopError` saying what is wrong with it: not
    (k, 2) numbers, ``n`` given and not k, a position not finite or outside ``[0, w] x [0, h]``.
    """
    xy = np.asarray(start_points)
    if xy.ndim != 2 or xy.shape[1] != 2 or not (np.issubdtype(xy.dtype, np.number) and not np.iscomplexobj(xy)):
        raise PatternshopError(f"start_points must be an (n, 2) array of positions, got shape {xy.shape} of {xy.dtype}")
    if n is not None and n != len(xy):
        raise PatternshopError(f"n = {n} but start_points holds {len(xy)} points: give one or make them agree")
    xy = np.array(xy, np.float64)
    if not np.isfinite(xy).all():
        raise PatternshopError("start_points holds positions that are not finite (nan or inf)")
    outside = ((xy < 0.0) | (xy > np.asarray(domain))).any(axis=1)
    if outside.any():
        raise PatternshopError(f"{int(outside.sum())} of the start_points lie outside the map's domain "
                               f"[0, {domain[0]:g}] x [0, {domain[1]:g}] (e.g. {xy[np.argmax(outside)].tolist()})")
    return xy


def reflect(xy: np.ndarray, domain: tuple[float, float]) -> np.ndarray:
    """Mirror positions (n, 2) back into ``[0, w) x [0, h)`` at the border, in place; returns the (n, 2) mask of mirrored coordinates."""
    size = np.asarray(domain, np.float64)
    below = xy < 0.0
    np.abs(xy, out=xy)
    beyond = xy > size
    xy[beyond] = (2 * np.broadcast_to(size, xy.shape))[beyond] - xy[beyond]
    np.clip(xy, 0.0, size * (1 - 1e-9), out=xy)
    return below | beyond


def synthesize(
    lab_map: LabMap,
    n: int | None = None,
    palette: Palette | None = None,
    schedule: str | Schedule = "fast",
    iterations: int | None = None,
    seed: int = 0,
    guide: bool = True,
    progress: bool = False,
    threads: int = 1,
    on_iteration: Callable[[int, np.ndarray], None] | None = None,
    start_points: np.ndarray | None = None,
) -> SynthesisResult:
    """Synthesise points for a map.

    Args:
        lab_map: target map (density from L, correlation from a, b).
        n: point count (default: :func:`point_count`).
        palette: correlation palette (default: the shipped one).
        schedule: ``"fast"`` or a :class:`Schedule`.
        iterations: override the schedule's iteration count.
        seed: random seed; the result is deterministic for a seed (and thread count).
        guide: use the guidance term (False gives the Roveri-style baseline).
        progress: show a progress bar with the loss and ETA on stderr.
        threads: threads of the numba kernels (1 is best on a busy 2-core machine).
        on_iteration: called as ``on_iteration(done, xy)`` with the steps done so far and
            the current (n, 2) positions: once with 0 before the first step (the
            density-matched start, a usable preview) and after every step (a live
            view, in an internal spatially sorted order that stays the same for the
            whole run: copy to keep).
        start_points: a warm start: (n, 2) positions in the map's domain coordinates (as the result's
            ``points.xy``), used instead of the density-matched start; n is their count (an error if ``n``
            is given and differs). Typically a previous result with the points of an edited region re-drawn
            for the new map (:func:`redrawn_start`). The run is the whole schedule, on a leash from these
            points: the points outside an edit stay near where they were (a converged pattern stays
            converged) and a re-drawn region converges as in a full run, which takes as many iterations
            (fewer leave it less regular: see docs/synthesis.md, "Warm start"). The result keeps their order.
    """
    with _collector_paused():  # the start-up's objects (numba, its kernels, the fields) are long-lived: see there
        import numba

        from synthesis.edgepcf import WindowSampler, find_neighbourhoods
        from synthesis.density_term import DensityTerm
        from synthesis.edgepcf_fast import FastObjective
        from synthesis.kernels import announce_compilation, load_cached_kernels_lazily
        from synthesis.neighbour_term import NeighbourTerm
        from synthesis.step_fast import hold_in_ink, momentum_step
        from synthesis.stratified import spatial_order

        start = time.perf_counter()
        try:
            plan = SCHEDULES[schedule] if isinstance(schedule, str) else schedule
        except KeyError:
            raise PatternshopError(f"unknown schedule {schedule!r}; choose one of: {', '.join(SCHEDULES)}") from None
        if iterations is not None and iterations < 0:
            raise PatternshopError(f"iterations must be >= 0, got {iterations}")
        if start_points is not None:
            start_points = checked_start_points(start_points, n, lab_map.domain)
            n = len(start_points)
        count = plan.iterations if iterations is None else iterations
        n = point_count(lab_map) if n is None else n
        if n < 2:
            raise PatternshopError(f"need at least 2 points, got {n}")
        load_cached_kernels_lazily()
        announce_compilation()
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
        rng = np.random.default_rng(seed)
        palette = palette or load_palette()
        fields = MapFields.build(lab_map, n, palette, guide=guide)
        tone = DensityTerm(lab_map, fields, plan.tone, plan.tone_scale) if plan.tone > 0 else None
        nearest = NeighbourTerm(fields, plan.neighbours)
        xy = initial_points(lab_map, n, rng, fields) if start_points is None else start_points
        if fields.nearest_ink is not None:  # a start drawn across a pixel edge into the white
            hold_in_ink_reference(xy, np.zeros_like(xy), fields.nearest_ink, fields.ink_side_px)
        order = spatial_order(xy, fields.domain)  # points stay sorted in memory along a Hilbert curve while they move
        xy = xy[order]
        if tone is not None:
            tone.hold_shares(xy)  # each point's regular share fixed for the run (density_term, "Correlation edges")
        windows, denominators, workspace = WindowSampler(fields), DenominatorTracker(fields), Workspace()
        start_xy = xy.copy()
        first, second = np.zeros_like(xy), 0.0
        beta1, beta2 = 0.9, 0.999
        setup = time.perf_counter() - start
    losses: list[float] = []
    step_length = leash = None
    bar = _progress_bar(count, f"synthesis (n={n})") if progress else _NoBar()
    if on_iteration is not None:
        on_iteration(0, xy)
    travelled = math.inf  # since the last refresh, in iterations at the initial step
    for step in range(count):
        rate = plan.rate(step, count)
        if travelled >= plan.refresh:
            travelled = 0.0
            hood = objective = None  # the old lists go before the new ones are built (peak memory)
            nearest.clear()
            hood = find_neighbourhoods(fields, xy, windows.draw(rng), denominators, workspace)
            objective = FastObjective(hood, threads, workspace)
            freedom = 1.0 + (plan.free_step - 1.0) * (1.0 - hood.regularity)
            step_length = hood.spacing * hood.structure * border_steps(fields, xy, hood.spacing, freedom)
            if nearest.active:
                nearest.refresh(hood.offsets, hood.neighbours, hood.anchor, hood.spacing, freedom)
            leash = plan.leash * hood.spacing * freedom
            if not step_length.any():  # white noise everywhere: no point can move, the start is the result
                if on_iteration is not None:
                    on_iteration(count, xy)
                bar.update(count - step)
                break
        loss, gradient = objective(xy)
        if tone is not None and tone.active:
            tone(xy, gradient)  # its gradient added; the loss recorded stays the PCF objective's (see absurd_run)
        if nearest.active:
            nearest(xy, gradient)  # likewise
        losses.append(loss)
        second = beta2 * second + (1 - beta2) * float(np.vdot(gradient, gradient)) / gradient.size
        travelled += rate / plan.step
        momentum_step(xy, first, gradient, start_xy, step_length, leash, rate, beta1, 1 - beta1 ** (step + 1),
                      math.sqrt(second / (1 - beta2 ** (step + 1))) + 1e-30, *fields.domain)
        if fields.nearest_ink is not None:
            hold_in_ink(xy, first, fields.nearest_ink, fields.ink_side_px)
        if on_iteration is not None:
            on_iteration(step + 1, xy)
        bar.set_postfix(loss=f"{loss:.4g}", refresh=False)
        bar.update()
    bar.close()
    points = np.empty_like(xy)
    points[order] = xy  # the start's order
    hood = objective = None  # final_loss builds lists of its own (1M points, 2 threads: peak 2.17 -> 1.86 GB)
    nearest.clear()
    final = final_loss(fields, xy, denominators, workspace, windows)
    return SynthesisResult(PointSet(points, fields.domain, points_per_ink=points_per_ink_of(lab_map, n)), plan.name, count,
                           time.perf_counter() - start, setup, losses, final,
                           absurd_run(losses[0] if losses else final, final, misplaced_share(lab_map, points)))


@contextlib.contextmanager
def _collector_paused() -> Iterator[None]:
    """Python's cyclic garbage collector off for the block, then as it was: a synthesis's start-up (numba's import, its
    cached kernels, the fields and the start) allocates some 10^5 objects that live on, and the collections that walked
    them took 30-70 ms of the 0.5 s to the first iteration (logo.tif, 10,000 points; issue 27). The iterations run with
    it as the caller had it."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if collecting:
            gc.enable()


def border_steps(fields: MapFields, xy: np.ndarray, spacing: np.ndarray, freedom: np.ndarray) -> np.ndarray:
    """(n,) the step factor of points at xy (n, 2) (local spacings ``spacing`` (n,), map units): ``freedom`` (n,), but
    within :data:`BORDER_STEP_BAND` spacings of the domain's border a point whose target's clusters are spread
    regularly (:func:`synthesis.edgepcf.spread_clusters_at`, green) takes the regular targets' step of 1 instead.

    Near the border the expected counts ``g D`` are linearised at each refresh, and a point that the long steps of a
    clustered target carry 1-2 spacings towards the border before the next sees its pairs drop without its expected
    counts: green's clusters, which repel each other (their PCF dips to 0.21 between them) and stand in windows with
    more pairs than the target, layered against the border (constant map, 4,096 points, 12 seeds: 1.17 / 1.17 of the
    expected density in the first two 0.5 r_max strips, 0.90 / 0.88 at 2-3 r_max; refreshed every 2 initial steps
    instead of 20: 1.01 / 0.94, 1.06 / 1.06). Red, whose windows lack pairs while its clusters form, is held off the
    border by shorter steps there (0.89 -> 0.64 in the first strip) and keeps its own; so do targets without clusters
    (the same steps). See docs/synthesis.md, "Green's border".
    """
    from synthesis.edgepcf import spread_clusters_at

    w, h = fields.domain
    near = np.minimum(np.minimum(xy[:, 0], w - xy[:, 0]), np.minimum(xy[:, 1], h - xy[:, 1])) < BORDER_STEP_BAND * spacing
    near = np.flatnonzero(near & (freedom > 1.0))
    spread = spread_clusters_at(fields, xy[near])
    near, spread = near[spread > 0], spread[spread > 0]
    if not len(near):
        return freedom  # the same steps, bit for bit
    steps = np.array(freedom, np.float64)
    steps[near] = 1.0 + (steps[near] - 1.0) * (1.0 - spread)
    return steps


def _progress_bar(total: int, description: str):  # noqa: ANN201 - a tqdm bar, imported here
    """A tqdm bar on stderr for ``total`` steps (tqdm is imported only when a bar is shown: 6 ms of start-up)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=description, unit="it", leave=False)


class _NoBar:
    """What :func:`synthesize` calls on its bar when none is shown."""

    def update(self, steps: int = 1) -> None:
        pass

    def set_postfix(self, **values: object) -> None:
        pass

    def close(self) -> None:
        pass


def momentum_step_reference(xy: np.ndarray, first: np.ndarray, gradient: np.ndarray, start_xy: np.ndarray,
                            step_length: np.ndarray, leash: np.ndarray, rate: float, beta1: float,
                            first_correction: float, denominator: float, width: float, height: float) -> None:
    """One step in place on positions xy (n, 2) and first moments (n, 2), plain numpy (the reference of
    :func:`synthesis.step_fast.momentum_step`).

    ``first <- beta1 first + (1 - beta1) gradient``; move by ``rate x step_length x (first / first_correction) /
    denominator`` (step_length (n,) in map units; denominator: the shared second moment's root, bias-corrected);
    mirror at the border (reversing the momentum there, :func:`reflect`); pull back within ``leash`` (n,) of start_xy.
    """
    first *= beta1
    first += (1 - beta1) * gradient
    xy -= rate * step_length[:, None] * ((first / first_correction) / denominator)
    first[reflect(xy, (width, height))] *= -1.0  # a mirror reverses the momentum too
    away = xy - start_xy
    xy -= away * (1.0 - np.minimum(1.0, leash[:, None] / np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-300)))


def hold_in_ink_reference(xy: np.ndarray, first: np.ndarray, nearest: np.ndarray, side_px: int) -> None:
    """Send points (n, 2) off ink back onto it, in place; plain numpy (the reference of :func:`synthesis.step_fast.hold_in_ink`).

    A point on a pixel without ink (``nearest``: (H, W, 2) int32 nearest inked pixel, see
    :func:`synthesis.fields.nearest_ink`; ``side_px`` pixels per map unit) is mirrored at the edge of the nearest
    inked pixel, or put on that edge where the mirror image would leave the pixel; its first moment (n, 2) reverses
    on the axes it was sent back along. Ink's edge holds points as the border does: the objective has no term that
    keeps them on ink (only the leash), and next to white a point's neighbours all lie on one side.
    """
    height, width, _ = nearest.shape
    pixel = np.stack(pixels_of(xy, (height, width), side_px), axis=1)
    target = nearest[pixel[:, 0], pixel[:, 1]]
    off = np.flatnonzero((target != pixel).any(axis=1))
    lo = target[off, ::-1] / side_px  # (x, y) of the inked pixel's corner
    hi = lo + 1.0 / side_px
    edge = np.clip(xy[off], lo, hi)
    mirrored = 2.0 * edge - xy[off]
    inside = (mirrored >= lo) & (mirrored < hi)
    held = np.where(inside.all(axis=1, keepdims=True), mirrored, np.minimum(edge, np.nextafter(hi, 0.0)))
    first[off] = np.where(edge != xy[off], -first[off], first[off])
    xy[off] = held


def final_loss(fields: MapFields, xy: np.ndarray, denominators: DenominatorTracker | None = None,
               workspace: Workspace | None = None, windows: WindowSampler | None = None) -> float:
    """The objective at positions xy (n, 2) with fresh pair lists and fixed-seed windows (comparable across runs and patterns).

    ``denominators``: the run's tracker, so only points that moved since their last evaluation are integrated again;
    ``workspace``: the run's buffers (overwritten); ``windows``: the run's window sampler (saves building one).
    """
    from synthesis.edgepcf import WindowSampler, find_neighbourhoods
    from synthesis.edgepcf_fast import FastObjective

    centres = (windows or WindowSampler(fields)).draw(np.random.default_rng(0))  # the fixed-seed windows
    hood = find_neighbourhoods(fields, xy, centres, denominators, workspace, slopes=False)  # at the anchors: no slopes
    return FastObjective(hood, workspace=workspace)(np.asarray(xy, np.float64), gradient=False)[0]
