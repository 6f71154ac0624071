"""The synthesiser's fast paths against their plain references: cell-grid queries, field sampling, guides,
per-point terms, compact denominators, buffer reuse, thread counts, and the CLI's progressive preview."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from patternshop import cli
from synthesis import points as points_module
from synthesis.cells import CellGrid
from synthesis.edgepcf import (POISSON_TOLERANCE, REGULAR_RANGE, STRUCTURE_RANGE, find_neighbourhoods, regularity, structure,
                               window_taper)
from synthesis.edgepcf_fast import FastObjective, cumulate, point_lists, point_terms, row_guides, window_weights
from synthesis.fields import (GUIDE_BANDWIDTH, DenominatorTracker, MapFields, guide_similarity, sample_grid,
                              sample_grid_reference, sample_table)
from synthesis.labmap import LabMap
from synthesis.mapio import write_tiff
from synthesis.palette import load_palette
from synthesis.pcf import neighbour_lists
from synthesis.stratified import spatial_order
from synthesis.synthesize import synthesize
from synthesis.workspace import Workspace


def split_map(size: tuple[int, int] = (40, 60)) -> LabMap:
    """Light blue left half, dark red right half: borders, a density edge and a correlation edge."""
    palette = load_palette()
    lab = np.zeros(size + (3,), np.float32)
    lab[:, : size[1] // 2] = (80.0, *palette.preset_ab()["blue"])
    lab[:, size[1] // 2 :] = (40.0, *palette.preset_ab()["red"])
    return LabMap(lab)


@pytest.mark.parametrize("periodic", [False, True])
def test_cell_grid_finds_exactly_the_tree_neighbours(periodic):
    rng = np.random.default_rng(0)
    domain = (1.0, 0.7)
    xy = rng.random((3000, 2)) * domain
    centres, reach = xy[:200], rng.uniform(0.005, 0.08, 200)
    offsets, index, distance = CellGrid(xy, domain, 0.02, periodic).query(centres, reach, exclude=np.arange(200))
    tree = cKDTree(xy, boxsize=list(domain) if periodic else None)
    ref_offsets, ref_index, ref_distance = neighbour_lists(tree, centres, reach)
    for c in range(200):
        ours = dict(zip(index[offsets[c]:offsets[c + 1]].tolist(), distance[offsets[c]:offsets[c + 1]]))
        theirs = {int(k): d for k, d in zip(ref_index[ref_offsets[c]:ref_offsets[c + 1]], ref_distance[ref_offsets[c]:ref_offsets[c + 1]])
                  if k != c}
        assert ours.keys() == theirs.keys()
        np.testing.assert_allclose([ours[k] for k in theirs], list(theirs.values()), rtol=1e-12)


@pytest.mark.parametrize("threads", [1, 2])
def test_cell_grid_queries_in_the_room_of_the_last_one(threads, monkeypatch):
    """A named query writes its lists in one pass into the room the last one of its name took (each run of centres
    from its share of the room, then side by side); one that needs more counts first: the lists are the same."""
    import numba

    from synthesis import cells

    scan, passes = cells._scan, []
    monkeypatch.setattr(cells, "_scan", lambda *args: (passes.append(1), scan(*args)))
    rng, domain, workspace, previous = np.random.default_rng(5), (1.0, 0.7), Workspace(), numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        calls = []
        for count, reach in ((3000, 0.03), (3000, 0.03), (2000, 0.02), (4000, 0.05)):  # the last needs more room
            xy = rng.random((count, 2)) * domain
            fresh = CellGrid(xy, domain, 0.03).query(xy, reach, exclude=np.arange(count))
            passes.clear()
            reused = CellGrid(xy, domain, 0.03).query(xy, reach, exclude=np.arange(count), workspace=workspace, name="p")
            calls.append(len(passes))
            for mine, theirs in zip(reused, fresh):
                np.testing.assert_array_equal(mine, theirs)
    finally:
        numba.set_num_threads(previous)
    assert calls == [2, 1, 1, 3]


def test_cell_grid_counts_each_point_once_on_a_small_torus():
    xy = np.random.default_rng(0).random((100, 2))
    offsets, index, _ = CellGrid(xy, (1.0, 1.0), 0.1, periodic=True).query(xy[:5], 0.6)  # reach beyond half the side
    ref_offsets, ref_index, _ = neighbour_lists(cKDTree(xy, boxsize=[1.0, 1.0]), xy[:5], 0.6)
    for c in range(5):
        found = index[offsets[c]:offsets[c + 1]].tolist()
        assert len(found) == len(set(found)) and set(found) == set(ref_index[ref_offsets[c]:ref_offsets[c + 1]].tolist())


def test_point_lists_gather_every_membership_of_both_families():
    fields = MapFields.build(split_map(), 1200, load_palette())
    xy = np.random.default_rng(6).random((1200, 2)) * fields.domain
    hood = find_neighbourhoods(fields, xy)
    offsets, window, weight = point_lists(hood.windows, len(xy))
    expected = {}
    first = 0
    for windows in hood.windows:
        for w in range(len(windows.offsets) - 1):
            for q in range(windows.offsets[w], windows.offsets[w + 1]):
                expected.setdefault(int(windows.members[q]), []).append((first + w, float(windows.weights[q])))
        first += len(windows.offsets) - 1
    for c in range(len(xy)):
        assert list(zip(window[offsets[c]:offsets[c + 1]].tolist(), weight[offsets[c]:offsets[c + 1]].tolist())) == expected.get(c, [])


def test_window_weights_match_taper_times_guide():
    rng = np.random.default_rng(7)
    latent, centres = rng.random((300, 2)) * 0.1, rng.random((10, 2)) * 0.1
    offsets = np.arange(0, 301, 30)
    members = rng.permutation(300).astype(np.int32)
    reach = rng.uniform(0.5, 1.0, 10)
    distance = rng.random(300) * 0.9
    rows = np.repeat(np.arange(10), 30)
    got = window_weights(distance, offsets, reach, latent, members, centres, GUIDE_BANDWIDTH, np.empty(300, np.float32))
    plain = window_taper(distance / reach[rows]) * guide_similarity(latent[members], centres[rows])
    np.testing.assert_allclose(got, plain, rtol=1e-6, atol=1e-7)


def test_field_sampling_and_guides_match_the_references():
    fields = MapFields.build(split_map(), 2000, load_palette())
    xy = np.random.default_rng(1).random((500, 2)) * fields.domain
    for grid in (fields.target, fields.latent, fields.spacing):
        np.testing.assert_array_equal(sample_grid(grid, xy, fields.side_px), sample_grid_reference(grid, xy, fields.side_px))
    assert len(fields.target_table) > 1  # the colour tables the kernels sample: the grids' values, bit for bit
    for table, grid in ((fields.target_table, fields.target), (fields.dispersion_table, fields.dispersion)):
        np.testing.assert_array_equal(sample_table(table, fields.colour, xy, fields.side_px),
                                      sample_grid_reference(grid, xy, fields.side_px))
    latent = fields.guide_at(xy)  # split_map: a density edge too
    assert np.ptp(latent[:, 2]) > 0.3  # beyond the dead zone (0.16)
    offsets, members, _ = CellGrid(xy, fields.domain, 0.05).query(xy, 0.1)
    rows = np.repeat(np.arange(len(xy)), np.diff(offsets))
    np.testing.assert_allclose(row_guides(latent, latent, offsets, members, GUIDE_BANDWIDTH),
                               guide_similarity(latent[members], latent[rows]), rtol=1e-12)


def test_point_terms_match_the_plain_formulas():
    fields = MapFields.build(split_map(), 2000, load_palette())
    xy = np.random.default_rng(2).random((800, 2)) * fields.domain
    denominators = DenominatorTracker(fields).update(xy)
    assert 0 < len(denominators.sloped) < len(xy)  # borders and the edge are stored, the rest is the exact value
    np.testing.assert_allclose(denominators.full(), fields.denominator_at(xy), rtol=1e-12)
    hood = find_neighbourhoods(fields, xy)
    members = (hood.member_offsets, hood.member_window, hood.member_weight)
    windows = sum(len(family.offsets) - 1 for family in hood.windows)
    short = int(np.sum(fields.radii <= REGULAR_RANGE))
    squares, regular, structured = point_terms(fields, xy, denominators, members, windows, short, POISSON_TOLERANCE,
                                               STRUCTURE_RANGE)
    target = sample_grid(fields.target, xy, fields.side_px).astype(np.float64)
    dispersion = sample_grid(fields.dispersion, xy, fields.side_px).astype(np.float64)
    variance = dispersion * (np.cumsum(target * fields.denominator_at(xy), axis=1) + 1.0)
    plain = np.zeros((windows, len(fields.radii)))
    first = 0
    for family in hood.windows:
        np.add.at(plain, first + family.owners, family.weights.astype(np.float64)[:, None] ** 2 * variance[family.members])
        first += len(family.offsets) - 1
    np.testing.assert_allclose(squares, plain, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(regular, regularity(target, fields.radii), atol=1e-6)
    np.testing.assert_allclose(structured, structure(target), atol=1e-6)
    np.testing.assert_allclose(hood.expected(), target * fields.denominator_at(xy), rtol=1e-12)


def test_tracker_recomputes_moved_points_and_carries_the_others():
    fields = MapFields.build(split_map(), 2000, load_palette())
    rng = np.random.default_rng(3)
    xy = rng.random((800, 2)) * fields.domain
    tracker = DenominatorTracker(fields)
    before = tracker.update(xy)
    slopes = np.zeros((len(xy), len(fields.radii), 2))
    slopes[before.sloped] = before.slopes
    moved = xy.copy()
    moved[:50] = rng.random((50, 2)) * fields.domain  # far: recomputed (some become uniform, some stored)
    moved[50:] += 1e-5  # near: carried along the slope
    after = tracker.update(moved)
    np.testing.assert_allclose(after.full()[:50], fields.denominator_at(moved[:50]), rtol=1e-12)
    carried = before.full()[50:] + np.einsum("kjd,kd->kj", slopes[50:], moved[50:] - xy[50:])
    np.testing.assert_allclose(after.full()[50:], carried, rtol=1e-12)


def test_reused_workspace_and_threads_give_the_same_objective():
    fields = MapFields.build(split_map(), 1500, load_palette())
    xy = np.random.default_rng(4).random((1500, 2)) * fields.domain
    xy = xy[spatial_order(xy, fields.domain)]
    workspace = Workspace()
    first = FastObjective(find_neighbourhoods(fields, xy, workspace=workspace), 1, workspace)(xy)
    loss, gradient = first[0], first[1].copy()
    again = FastObjective(find_neighbourhoods(fields, xy, workspace=workspace), 2, workspace)(xy)  # same buffers, 2 runs
    assert again[0] == pytest.approx(loss, rel=1e-12)
    np.testing.assert_allclose(again[1], gradient, rtol=1e-9, atol=1e-12 * np.abs(gradient).max())


def test_one_colour_objective_skips_its_guides_with_the_same_bits():
    """On a one-colour map every pair's guide is 1 and the window sums do not read them: the same loss and gradient,
    bit for bit, as with the guides read."""
    lab = np.zeros((32, 32, 3), np.float32)
    lab[...] = (50.0, *load_palette().preset_ab()["blue"])
    fields = MapFields.build(LabMap(lab), 1500, load_palette())
    rng = np.random.default_rng(6)
    xy = rng.random((1500, 2)) * fields.domain
    xy = xy[spatial_order(xy, fields.domain)]
    hood = find_neighbourhoods(fields, xy)
    assert not hood.guided and np.all(hood.guide == 1.0)
    moved = np.clip(xy + rng.normal(0.0, 1e-3, xy.shape), 0.0, 0.999)  # away from the anchors: the kernel counts
    skipped = FastObjective(hood)(moved)
    loss, gradient = skipped[0], skipped[1].copy()
    hood.guided = True
    read = FastObjective(hood)(moved)
    assert read[0] == loss and np.array_equal(read[1], gradient)


@pytest.mark.parametrize("threads", [1, 2])
def test_final_loss_without_slopes_is_the_full_objective_at_the_anchors(threads):
    """final_loss builds its neighbourhoods without the expected counts' slopes, their levels and the variance force
    (each meets a move of 0 at the anchors): the same loss bit for bit as the full refresh's objective there."""
    import numba

    from synthesis.edgepcf import WindowSampler
    from synthesis.synthesize import final_loss

    fields = MapFields.build(split_map(), 1500, load_palette())
    xy = np.random.default_rng(5).random((1500, 2)) * fields.domain
    xy = xy[spatial_order(xy, fields.domain)]
    centres = WindowSampler(fields).draw(np.random.default_rng(0))
    with_threads = min(threads, numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(with_threads)
    try:
        hood = find_neighbourhoods(fields, xy, centres)
        assert len(hood.sloped) and np.abs(hood.variance_force).max() > 0  # borders and edges: slope terms to skip
        full = FastObjective(hood)(xy, gradient=False)[0]
        assert final_loss(fields, xy) == full
        assert final_loss(fields, xy, workspace=Workspace()) == full
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


def test_first_objective_call_at_the_anchors_reads_the_refresh_counts():
    """On one thread the refresh's window sums leave their tent counts, bins and pulls in the objective's buffers: its
    first evaluation at the anchors reads them (no counting pass) with the same loss and gradient bit for bit; any
    later evaluation counts."""
    import numba

    fields = MapFields.build(split_map(), 1500, load_palette())
    xy = np.random.default_rng(7).random((1500, 2)) * fields.domain
    xy = xy[spatial_order(xy, fields.domain)]
    numba.set_num_threads(1)
    try:
        workspace = Workspace()
        hood = find_neighbourhoods(fields, xy, workspace=workspace)
        assert hood.anchor_counts is not None and len(hood.sloped)
        objective = FastObjective(hood, 1, workspace)
        passes = []
        count = objective.window_sums_of_counts
        objective.window_sums_of_counts = lambda *args: passes.append(1) or count(*args)
        loss, gradient = objective(xy)
        assert passes == [] and hood.anchor_counts is None
        fresh = FastObjective(hood, 1, Workspace())(xy)  # counted again, in buffers of its own
        assert loss == fresh[0]
        np.testing.assert_array_equal(gradient, fresh[1])
        objective(xy)
        assert passes == [1]
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


@pytest.mark.parametrize("shape", [(300, 52), (300, 52, 2), (0, 52, 2), (5, 1)])
def test_cumulate_is_numpys_cumsum_bit_for_bit(shape):
    values = np.random.default_rng(11).standard_normal(shape) * 10.0 ** np.random.default_rng(12).integers(-8, 8, shape)
    expected = np.cumsum(values, axis=1)
    result = cumulate(values)
    assert result is values
    np.testing.assert_array_equal(result, expected)


def test_objective_variance_force_term_is_the_plain_sum_away_from_the_anchors():
    """The objective's loss away from the anchors: its windows' losses plus ``sum(variance_force * (xy[sloped] -
    anchor[sloped]))``, bit for bit, though it gathers into a reused buffer (called twice: the buffer is refilled)."""
    fields = MapFields.build(split_map(), 1500, load_palette())
    rng = np.random.default_rng(9)
    xy = rng.random((1500, 2)) * fields.domain
    xy = xy[spatial_order(xy, fields.domain)]
    hood = find_neighbourhoods(fields, xy)
    assert len(hood.sloped) and np.abs(hood.variance_force).max() > 0
    objective = FastObjective(hood, 1)
    for scale in (1e-3, 2e-3):
        moved = np.clip(xy + scale * rng.standard_normal(xy.shape), 0.0, np.asarray(fields.domain) * (1 - 1e-9))
        loss = objective(moved, gradient=False)[0]
        plain = float(np.sum(hood.variance_force * (moved[hood.sloped] - hood.anchor[hood.sloped])))
        assert plain != 0.0 and loss == float(objective.losses.sum()) + plain


def test_window_sums_share_one_buffer_without_overwriting_the_expected_sums():
    """The iterations' float32 window sums lie in the refresh's float64 parts past the first, which keeps the expected
    counts' sums (``window_expected``) for the whole refresh; a refresh's level-only tent sums are the full ones on the
    level windows; the windows' weight totals are numpy's bincount, bit for bit."""
    from synthesis.edgepcf_fast import _window_buffers, window_bounds, window_sums, window_totals

    for threads in (1, 2, 3):
        parts, sums = _window_buffers(Workspace(), threads, 7, 5)
        assert parts.shape == sums.shape == (threads, 7, 5) and (parts.dtype, sums.dtype) == (np.float64, np.float32)
        assert not np.shares_memory(parts[0], sums)
    fields = MapFields.build(split_map(), 1500, load_palette())
    xy = np.random.default_rng(6).random((1500, 2)) * fields.domain
    xy = xy[spatial_order(xy, fields.domain)]
    workspace = Workspace()
    hood = find_neighbourhoods(fields, xy, workspace=workspace)
    kept = hood.window_expected.copy()
    objective = FastObjective(hood, 2, workspace)
    for shift in (0.0, 1e-3):
        objective(xy + shift)
    np.testing.assert_array_equal(hood.window_expected, kept)
    full, _ = window_sums(hood, xy)
    level, _ = window_sums(hood, xy, level_only=True)
    bounds = window_bounds(hood.windows)
    for family, lo, hi in zip(hood.windows, bounds[:-1], bounds[1:]):
        np.testing.assert_array_equal(level[lo:hi], full[lo:hi] if family.scale.level else 0.0)
        np.testing.assert_array_equal(window_totals(family.offsets, family.weights),
                                      np.bincount(family.owners, family.weights, minlength=hi - lo))


def test_synthesis_returns_points_in_the_start_order():
    lab_map = split_map((24, 36))
    start = []
    result = synthesize(lab_map, n=400, seed=5, iterations=0, on_iteration=lambda done, xy: start.append(xy.copy()))
    assert len(start) == 1 and sorted(map(tuple, start[0])) == sorted(map(tuple, result.points.xy))
    assert not np.array_equal(start[0], result.points.xy)  # the callback sees the sorted order, the result the start's


def test_cli_preview_every_writes_intermediate_points_then_removes_them(tmp_path, monkeypatch):
    map_path, out = tmp_path / "m.tif", tmp_path / "p.txt"
    write_tiff(split_map((24, 36)), map_path)
    writes = []
    original = points_module.write_points

    def recording(points, path):  # noqa: ANN001, ANN202
        writes.append((str(path), len(points)))
        original(points, path)

    monkeypatch.setattr(points_module, "write_points", recording)
    argv = ["synthesize", str(map_path), str(out), "--points", "300", "--iterations", "10", "--preview-every", "4", "--no-progress"]
    assert cli.main(argv) == 0
    preview = str(tmp_path / "p.preview.txt")
    assert [path for path, _ in writes] == [preview] * 3 + [str(out)]  # the start, steps 4 and 8, then the result
    assert all(count == 300 for _, count in writes)
    assert out.exists() and not (tmp_path / "p.preview.txt").exists()


def test_cli_preview_needs_preview_every(tmp_path, capsys):
    map_path = tmp_path / "m.tif"
    write_tiff(split_map((24, 36)), map_path)
    assert cli.main(["synthesize", str(map_path), str(tmp_path / "p.txt"), "--preview", str(tmp_path / "q.txt")]) != 0
    assert "--preview needs --preview-every" in capsys.readouterr().err


def test_border_shares_match_dense_angular_sampling():
    from synthesis.fields_fast import border_shares

    rng = np.random.default_rng(1)
    width, height = 1.0, 0.7
    x = np.concatenate([rng.random(100) * 0.05, rng.random(100) * width, width - rng.random(50) * 0.05])
    y = np.concatenate([rng.random(100) * 0.05, height - rng.random(100) * 0.04, rng.random(50) * height])
    radii = np.linspace(0.001, 0.08, 20)
    shares = border_shares(x, y, np.ones_like(x), width, height, radii)
    theta = (np.arange(20000) + 0.5) / 20000 * 2 * np.pi
    px = x[:, None, None] + radii[None, :, None] * np.cos(theta)
    py = y[:, None, None] + radii[None, :, None] * np.sin(theta)
    dense = ((px >= 0) & (px <= width) & (py >= 0) & (py <= height)).mean(-1)
    np.testing.assert_allclose(shares, dense, atol=5e-4)


def test_border_denominators_agree_with_the_quadrature():
    palette = load_palette()
    lab = np.zeros((48, 72, 3), np.float32)
    lab[...] = (50.0, *palette.preset_ab()["blue"])
    fields = MapFields.build(LabMap(lab), 5000, palette)
    rng = np.random.default_rng(0)
    xy = np.concatenate([rng.random((200, 2)) * [0.03, fields.domain[1]], rng.random((100, 2)) * 0.03])  # a side, a corner
    todo, values, _ = fields.nonuniform_denominators(xy, slope=False)
    assert fields.flat[(xy[todo, 1] * fields.side_px).astype(int), (xy[todo, 0] * fields.side_px).astype(int)].all()
    at = xy[todo]
    spacing = sample_grid(fields.spacing, at, fields.side_px)[:, 0].astype(np.float64)
    quadrature = fields._quadrature_reference(at, spacing, fields.guide_at(at),
                                              sample_grid(fields.intensity, at, fields.side_px)[:, 0]) * fields.exact_denominator
    # the closed form is the quadrature's limit: they differ by its node noise (8 nodes on the smallest rings)
    assert np.abs(values - quadrature).mean() < 0.01 * fields.exact_denominator.mean()
    assert (np.abs(values - quadrature) <= 0.15 * fields.exact_denominator).all()  # one node of a 9-node ring is 11 %


def test_fused_momentum_step_matches_the_reference():
    from synthesis.step_fast import momentum_step
    from synthesis.synthesize import momentum_step_reference

    rng = np.random.default_rng(8)
    n, domain = 500, (1.0, 0.6)
    xy = rng.random((n, 2)) * domain
    xy[:20] = rng.random((20, 2)) * 0.002  # at the border: some steps cross it and are mirrored
    start = xy + rng.normal(0.0, 0.01, xy.shape)
    first, gradient = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    step_length, leash = rng.uniform(0.001, 0.05, n), rng.uniform(0.005, 0.03, n)
    args = (start, step_length, leash, 0.3, 0.9, 0.4, 0.8, *domain)
    ours, ours_first = xy.copy(), first.copy()
    momentum_step(ours, ours_first, gradient, *args)
    plain, plain_first = xy.copy(), first.copy()
    momentum_step_reference(plain, plain_first, gradient, *args)
    np.testing.assert_allclose(ours, plain, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(ours_first, plain_first)
    assert (ours_first[:20] != first[:20] * 0.9 + gradient[:20] * 0.1).any()  # some momenta were reversed


def test_variance_force_matches_a_plain_sum():
    from synthesis.edgepcf import CUMULATIVE_VARIANCE

    fields = MapFields.build(split_map(), 1200, load_palette())
    xy = np.random.default_rng(9).random((1200, 2)) * fields.domain
    hood = find_neighbourhoods(fields, xy)
    assert len(hood.sloped) > 50
    dispersion = sample_grid(fields.dispersion, xy[hood.sloped], fields.side_px).astype(np.float64)
    target_slope = sample_grid(fields.target, xy[hood.sloped], fields.side_px)[..., None] * hood.denominators.slopes
    variance_slope = dispersion[..., None] * np.cumsum(target_slope, axis=1)  # the target's variance (not the level's)
    model = CUMULATIVE_VARIANCE[0] + CUMULATIVE_VARIANCE[1] * (fields.radii + fields.radii[1])
    slot = np.full(len(xy), -1)
    slot[hood.sloped] = np.arange(len(hood.sloped))
    plain = np.zeros((len(hood.sloped), 2))
    for family in hood.windows:
        if not family.scale.compensation:
            continue
        per_point = np.zeros((len(hood.sloped), len(fields.radii)))
        owners = family.owners
        for q in np.flatnonzero(slot[family.members] >= 0):
            per_point[slot[family.members[q]]] += float(family.weights[q]) ** 2 * model / family.deviation[owners[q]].astype(np.float64) ** 2
        scale = family.scale.compensation * family.scale.weight / family.deviation.size
        plain -= scale * np.einsum("kj,kjd->kd", per_point, variance_slope)
    np.testing.assert_allclose(hood.variance_force, plain, rtol=1e-6, atol=1e-9 * np.abs(plain).max())  # float32 weights


def test_window_sums_and_slope_levels_equal_plain_numpy():
    from synthesis.edgepcf import LEVEL_PRIOR, pair_counts_reference, slope_levels
    from synthesis.edgepcf_fast import window_sums

    fields = MapFields.build(split_map(), 1200, load_palette())
    xy = np.random.default_rng(5).random((1200, 2)) * fields.domain
    hood = find_neighbourhoods(fields, xy)
    observed, expected = window_sums(hood, xy)
    plain_observed = np.concatenate([family.aggregate(pair_counts_reference(xy, hood)) for family in hood.windows])
    plain_expected = np.concatenate([family.aggregate(hood.expected()) for family in hood.windows])
    np.testing.assert_allclose(observed, plain_observed, rtol=1e-5, atol=1e-4)  # float32 sums
    np.testing.assert_allclose(expected, plain_expected, rtol=1e-6, atol=1e-6)  # float32 target and weights
    np.testing.assert_array_equal(expected, hood.window_expected)
    levels = slope_levels(hood, plain_observed, plain_expected)
    plain = np.ones((len(hood.sloped), len(fields.radii)))
    first = len(hood.windows[0].offsets) - 1  # the level windows (the regional family) come second
    regional = hood.windows[1]
    assert regional.scale.level and not hood.windows[0].scale.level
    prior = LEVEL_PRIOR * np.bincount(regional.owners, regional.weights, minlength=len(regional.offsets) - 1)[:, None]
    level = (np.cumsum(plain_observed[first:], axis=1) + prior) / (np.cumsum(plain_expected[first:], axis=1) + prior)
    for k, c in enumerate(hood.sloped):
        mine = regional.members == c
        if mine.any():
            a2 = regional.weights[mine].astype(np.float64) ** 2
            plain[k] = a2 @ level[regional.owners[mine]] / a2.sum()
    np.testing.assert_allclose(levels, plain, rtol=1e-6)
    red = xy[hood.sloped, 0] > 0.5 * fields.domain[0]
    assert levels[red, 6:12].mean() < 0.6  # independent points hold too few of the red half's pairs ...
    assert levels[~red, 12:20].mean() > 1.2  # ... and too many of the blue half's: the slopes follow the pattern


def test_neighbour_term_fast_path_equals_the_reference():
    from synthesis.neighbour_term import NeighbourTerm

    fields = MapFields.build(split_map(), 1200, load_palette())  # two spacings and targets: asymmetric pair lists too
    xy = np.random.default_rng(5).random((1200, 2)) * fields.domain
    xy[1], xy[3] = xy[0] + [1e-3, 0.0], xy[2]  # a close pair in the blue half and a stacked one (no direction)
    hood = find_neighbourhoods(fields, xy)
    term = NeighbourTerm(fields, 1e3)
    term.refresh(hood.offsets, hood.neighbours, hood.anchor, hood.spacing)
    moved = xy + np.random.default_rng(6).normal(0.0, 1e-3, xy.shape)
    moved[3] = moved[2]
    loss, gradient = term.reference(moved)
    added = np.full((1200, 2), 0.25)
    assert term(moved, added) == pytest.approx(loss, rel=1e-12)
    np.testing.assert_allclose(added - 0.25, gradient, rtol=1e-9, atol=1e-12 * np.abs(gradient).max())
    assert np.count_nonzero(gradient.any(axis=1)) > 100  # barrier and pulls both at work
    assert term(moved) == pytest.approx(loss, rel=1e-12)


def test_neighbour_term_short_lists_equal_plain_numpy():
    from synthesis.neighbour_term import short_lists, short_lists_reference

    fields = MapFields.build(split_map(), 1200, load_palette())
    xy = np.random.default_rng(7).random((1200, 2)) * fields.domain
    xy[1] = xy[0]  # a stacked pair: ties at the nearest
    hood = find_neighbourhoods(fields, xy)
    lower, upper, slack = 0.76 * hood.spacing, 1.03 * hood.spacing, 0.25 * hood.spacing
    fast = short_lists(xy, hood.offsets, hood.neighbours, lower, upper, slack)
    plain = short_lists_reference(xy, hood.offsets, hood.neighbours, lower, upper, slack)
    for mine, theirs in zip(fast, plain):
        np.testing.assert_array_equal(mine, theirs)
    assert 0 < fast[2].sum() < len(xy) and 0 < len(fast[1]) < len(hood.neighbours)  # candidates and a real filter


@pytest.mark.parametrize("correlation_edge", [True, False])
def test_tone_term_fast_path_equals_the_reference(correlation_edge):
    """With a correlation edge the counts are split by regularity (weighted splat, shares times the numba gradient);
    without one (blue on both sides of the density edge) the numba splat."""
    from synthesis.density_term import DensityTerm

    lab_map = split_map()
    if not correlation_edge:
        lab = np.array(lab_map.lab, np.float32)
        lab[..., 1:] = load_palette().preset_ab()["blue"]
        lab_map = LabMap(lab)
    fields = MapFields.build(lab_map, 1200, load_palette())
    term = DensityTerm(lab_map, fields, weight=1e4, scale=3.0)
    assert (term.regular_px is not None) == correlation_edge and term.tau is not None
    xy = np.random.default_rng(3).random((1200, 2)) * fields.domain
    xy[:5] = [[0.0, 0.0], [fields.domain[0] * (1 - 1e-9), 0.3], [0.2, fields.domain[1] * (1 - 1e-9)], [0.5, 0.0], [1e-6, 0.2]]
    loss, gradient = term.reference(xy)
    added = np.full((1200, 2), 0.25)
    fast_loss = term(xy, added)
    assert fast_loss == pytest.approx(loss, rel=1e-12)
    np.testing.assert_allclose(added - 0.25, gradient, rtol=1e-9, atol=1e-12 * np.abs(gradient).max())  # added into
    assert term(xy) == pytest.approx(loss, rel=1e-12)


def test_edge_blur_fast_path_equals_the_reference():
    """The tone term's edge-stopping blur: numba's pass equals the numpy reference, the 2-D blur's adjoint is its
    transpose, and with every transmittance 1 it is the plain Gaussian blur."""
    from synthesis.density_term import edge_blur, edge_pass_reference
    from synthesis.fields_fast import edge_pass, gaussian_blur, gaussian_taps

    rng = np.random.default_rng(5)
    for shape, sigma in [((30, 41), (3.0, 2.5)), ((1, 9), (3.0, 3.0)), ((12, 2), (0.6, 5.0))]:
        values, other = rng.random(shape) - 0.3, rng.random(shape)
        taps = (gaussian_taps(sigma[0], 3.0), gaussian_taps(sigma[1], 3.0))
        tau = (rng.random((shape[0], shape[1] - 1)), rng.random((shape[1], shape[0] - 1)))
        out = np.empty(shape)
        edge_pass(values, taps[1], tau[0], out)
        np.testing.assert_allclose(out, edge_pass_reference(values, taps[1], tau[0]), rtol=1e-13, atol=1e-15)
        for adjoint in (False, True):
            np.testing.assert_allclose(edge_blur(values, taps, tau, True, adjoint), edge_blur(values, taps, tau, False, adjoint),
                                       rtol=1e-12, atol=1e-15)
        assert np.vdot(other, edge_blur(values, taps, tau)) == pytest.approx(
            np.vdot(edge_blur(other, taps, tau, adjoint=True), values), rel=1e-12)
        ones = tuple(np.ones_like(t) for t in tau)
        np.testing.assert_allclose(edge_blur(values, taps, ones), gaussian_blur(values, sigma, 3.0), rtol=0, atol=1e-14)


def test_image_filters_equal_scipy_ndimage():
    """The synthesis path's own filters (scipy.ndimage is not imported before a synthesis's first iteration) against
    scipy's: the tone term's Gaussian blur within 1e-13 and its tent filter within 1e-14 (rounding: another summation
    order), the flatness test's max - min filter, the density level's running median (on values with ties and flat runs
    too) and the nearest-ink feature transform's distances exactly."""
    from scipy import ndimage

    from synthesis.density_term import TENT, _tent_filter
    from synthesis.fields import _window_spread
    from synthesis.fields_fast import gaussian_blur, nearest_true, running_median

    rng = np.random.default_rng(11)
    for shape, sigma in [((102, 102), (3.0, 3.0)), ((7, 40), (2.5, 3.7)), ((1, 9), (3.0, 3.0)), ((30, 2), (0.6, 5.0))]:
        values = rng.random(shape) - 0.3
        scipy_blur = ndimage.gaussian_filter(values, sigma, mode="constant", truncate=3.0)
        np.testing.assert_allclose(gaussian_blur(values, sigma, 3.0), scipy_blur, rtol=0, atol=1e-13)
        tent = ndimage.correlate1d(ndimage.correlate1d(values, TENT, axis=0, mode="constant"), TENT, axis=1, mode="constant")
        np.testing.assert_allclose(_tent_filter(values), tent, rtol=0, atol=1e-14)
        for half in (1, 2, 5, 64):
            size = 2 * half + 1
            spread = ndimage.maximum_filter(values, size, mode="nearest") - ndimage.minimum_filter(values, size, mode="nearest")
            np.testing.assert_array_equal(_window_spread(values, half), spread)
            np.testing.assert_array_equal(running_median(values, half), ndimage.median_filter(values, (1, size), mode="nearest"))
            steps = np.round(values * 4) / 4  # ties and flat runs, as on a map's flat areas (the sliding window's shortcut)
            np.testing.assert_array_equal(running_median(steps, half), ndimage.median_filter(steps, (1, size), mode="nearest"))
    for shape, share in [((60, 80), 0.01), ((256, 256), 0.3), ((1, 100), 0.05), ((100, 1), 0.05), ((40, 40), 0.0)]:
        mask = rng.random(shape) < share
        mask.flat[7] = True
        nearest = nearest_true(mask)
        assert mask[nearest[..., 0], nearest[..., 1]].all()
        rows, cols = np.indices(shape)
        squared = (nearest[..., 0] - rows) ** 2 + (nearest[..., 1] - cols) ** 2
        np.testing.assert_array_equal(squared, np.rint(ndimage.distance_transform_edt(~mask) ** 2))


@pytest.mark.parametrize("extent", [1.0, 1.37])
def test_stratified_cell_masses_are_the_density_integrated_over_the_cells(extent):
    """The start's cell grid (summed-area table) against a plain integral of the density, constant on each pixel, over
    each cell's part inside the domain (per-axis overlaps of cells and pixels), on a map with ink, white, a sharp step
    and a thin strip of domain in the last cells."""
    from synthesis.stratified import _cell_grid

    density = np.zeros((37, 50))
    density[5:30, 10:45] = np.linspace(0.1, 1.0, 35)
    density[:, 20:23] = 0.9
    side_px, domain = 50, (1.0, 37 / 50)
    order, mass = _cell_grid(density, side_px, domain, 3000, extent)
    side = 1 << order

    def overlaps(size: int, length: float) -> np.ndarray:  # (side, size) length of cell k inside the domain in pixel j
        lo = np.arange(side)[:, None] / side * extent
        hi = np.minimum(lo + extent / side, length)
        return np.clip(np.minimum(hi, (np.arange(size)[None] + 1) / side_px) - np.maximum(lo, np.arange(size)[None] / side_px),
                       0.0, None)

    integral = overlaps(37, domain[1]) @ density @ overlaps(50, domain[0]).T
    assert 0 < np.count_nonzero(integral) < side * side  # cells beyond the domain: the comparison covers both kinds
    np.testing.assert_allclose(mass, integral * (side / extent) ** 2, rtol=1e-9, atol=1e-9)
