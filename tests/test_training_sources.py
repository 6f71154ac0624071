"""Issue 28's training data: the other stipplers (data_gen/stipplers.py) and the texture maps (data_gen/makers/textures.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from data_gen.makers import build_maker
from data_gen.makers.textures import DEFAULT_TEXTURES, MIN_MEAN, TEXTURES, leaf_radii, texture_picture
from data_gen.pairs import PairSettings, generate
from data_gen.provenance import compose_config
from data_gen.shards import load_pairs, map_to_target, target_to_map
from data_gen.stipplers import DEFAULT_METHODS, LABELS, METHODS, bayer_matrix
from synthesis.errors import PatternshopError
from synthesis.synthesize import point_count
from synthesis.palette import load_palette

NEW = ("floyd_steinberg", "jarvis", "floyd_steinberg_jitter", "bayer", "lloyd_few", "lloyd_many")


def gradient(shape=(40, 60)) -> np.ndarray:
    return np.tile(np.linspace(0.1, 0.9, shape[1]), (shape[0], 1))


@pytest.mark.parametrize("method", NEW)
def test_new_stipplers_make_about_n_points_deterministically(method):
    density, domain, n = gradient(), (1.0, 40 / 60), 800
    xy = METHODS[method](density, n, domain, np.random.default_rng(3))
    assert abs(len(xy) - n) <= 0.04 * n
    assert np.all((xy >= 0) & (xy <= domain))
    np.testing.assert_array_equal(xy, METHODS[method](density, n, domain, np.random.default_rng(3)))
    right, left = np.sum(xy[:, 0] > 0.5), np.sum(xy[:, 0] < 0.5)
    assert right > 1.5 * left  # the density's gradient: about 2.3 times as many on the right


def test_every_training_method_has_a_label_and_the_defaults_are_unchanged():
    assert set(METHODS) == set(LABELS)
    assert DEFAULT_METHODS == ("random", "lloyd", "poisson_disk", "jitter", "clusters")
    assert all(isinstance(LABELS[name], str) for name in DEFAULT_METHODS)
    assert all(len(LABELS[name]) == 2 for name in NEW)  # measured a, b
    assert sorted(bayer_matrix(2).ravel() * 16 - 0.5) == list(range(16))


@pytest.mark.parametrize("kind", sorted(TEXTURES))
def test_textures_are_deterministic_and_in_range(kind):
    first = TEXTURES[kind](48, np.random.default_rng(5))
    assert first.shape == (48, 48) and first.dtype == np.float32
    assert 0.0 <= first.min() and first.max() <= 1.0 and first.std() > 0.02
    np.testing.assert_array_equal(first, TEXTURES[kind](48, np.random.default_rng(5)))
    assert not np.array_equal(first, TEXTURES[kind](48, np.random.default_rng(6)))
    _, toned = texture_picture(48, np.random.default_rng(5), {kind: 1.0})
    assert toned.mean() >= MIN_MEAN - 1e-6 and 0.0 <= toned.min() and toned.max() <= 1.0


def test_dead_leaves_are_opt_in_and_their_radii_follow_r_to_the_minus_3():
    assert "dead_leaves" in TEXTURES and "dead_leaves" not in DEFAULT_TEXTURES  # earlier folders' commands unchanged
    radii = leaf_radii(200_000, 2.0, 60.0, np.random.default_rng(0))
    assert radii.min() >= 2.0 and radii.max() <= 60.0
    for r in (4.0, 8.0, 20.0):  # P(R > r) = (r^-2 - b^-2) / (a^-2 - b^-2)
        expected = (r**-2 - 60.0**-2) / (2.0**-2 - 60.0**-2)
        assert abs(np.mean(radii > r) - expected) < 0.005


def test_textures_dataset_is_deterministic():
    maker = build_maker({"name": "textures", "items": 4}, 32)
    first = maker.make(0, np.random.default_rng([0, 0])).lab
    np.testing.assert_array_equal(first, maker.make(0, np.random.default_rng([0, 0])).lab)
    assert len(maker) == 4 and first.shape == (32, 32, 3)


def test_new_options_leave_the_default_pairs_and_key_unchanged():
    def key(*overrides):
        return PairSettings.from_config(compose_config("pairs", ["map_size=32", *overrides])).key()

    assert key() == key("textures.kinds={text: 1.0}") != key("textures.share=0.5")
    shipped = ["other_methods.share=0.35"]
    weights_only = "other_methods.methods={random: 1.0, lloyd: 1.0, poisson_disk: 1.0, jitter: 1.0, clusters: 1.0}"
    assert key(*shipped) == key(*shipped, weights_only)  # the zero-weight new methods are not part of the key
    assert key(*shipped) != key(*shipped, "other_methods.methods.bayer=1.0")


def test_tiny_pairs_run_with_textures_and_new_stipplers(tmp_path):
    folder = tmp_path / "pairs"
    methods = [f"other_methods.methods.{name}={float(name in ('jarvis', 'bayer', 'lloyd_few', 'floyd_steinberg_jitter'))}"
               for name in METHODS]
    generate(compose_config("pairs", [f"out_dir={folder}", "num_items=4", "workers=1", "map_size=48", "raster_size=48",
                                      "synthesis.points_per_ink=1500", "other_methods.share=1.0", *methods,
                                      "textures.share=1.0"]))
    pairs = load_pairs(folder)
    assert len(pairs.meta) == 4
    for k, meta in enumerate(pairs.meta):
        a, b = LABELS[meta["method"]]
        target = pairs.target[k]
        assert np.all(target[..., 1] == round(a) + 128) and np.all(target[..., 2] == round(b) + 128)
        assert meta["method"] in ("jarvis", "bayer", "lloyd_few", "floyd_steinberg_jitter")
        wanted = point_count(target_to_map(target), 1500)
        assert abs(len(pairs.points_of(k)) - wanted) <= 0.1 * wanted, (meta, wanted)


# --- network v6's draws (conf/generation/v6.yaml): points per ink log-uniform, lattices at random rotations ----------
def scale_settings(share: float = 1.0) -> PairSettings:
    return PairSettings.from_config(compose_config("pairs", ["map_size=32", f"scale.share={share}"]))


def test_points_per_ink_draw_is_log_uniform_over_its_range():
    from scipy.stats import kstest

    from data_gen.pairs import scale_variant

    settings = scale_settings()
    low, high = settings.scale["points_per_ink"]
    lab_map = target_to_map(np.full((32, 32, 3), 128, np.uint8))
    rng = np.random.default_rng(0)
    drawn = np.array([scale_variant(settings, lab_map, rng)[1] for _ in range(400)])
    assert low <= drawn.min() and drawn.max() <= high
    logs = (np.log(drawn) - np.log(low)) / (np.log(high) - np.log(low))
    assert kstest(logs, "uniform").pvalue > 0.01  # a uniform draw in ppi would put 98 % above the middle of the log range
    assert 0.4 < np.mean(drawn < np.sqrt(low * high)) < 0.6
    assert scale_variant(scale_settings(0.0), lab_map, rng) == (lab_map, settings.points_per_ink)


def test_scale_zooms_the_map_above_the_base_and_lightens_it_below():
    from data_gen.pairs import scale_variant, zoom_window

    ramp = np.tile(np.linspace(0.0, 1.0, 64), (64, 1))
    lab = np.stack([100 * (1 - ramp), np.zeros_like(ramp), np.zeros_like(ramp)], -1)
    zoomed = zoom_window(lab, 4.0, np.random.default_rng(1))
    assert zoomed.shape == lab.shape
    slope = np.diff(zoomed[32, :, 0]).mean()
    assert slope == pytest.approx(np.diff(lab[32, :, 0]).mean() / 4.0, rel=0.05)  # a quarter of the map, 4 times wider
    settings = scale_settings()
    lab_map = target_to_map(np.stack([np.full((32, 32), 100, np.uint8), np.full((32, 32), 128, np.uint8),
                                      np.full((32, 32), 128, np.uint8)], -1))  # density 0.6 (L = 40 stored as 100/255)
    for seed in range(20):
        scaled, drawn = scale_variant(settings, lab_map, np.random.default_rng(seed))
        if drawn < settings.points_per_ink:  # lightened by drawn / base
            assert scaled.density().mean() == pytest.approx(lab_map.density().mean() * drawn / settings.points_per_ink, abs=0.01)
        else:  # a uniform map stays uniform when zoomed
            assert scaled.density().mean() == pytest.approx(lab_map.density().mean(), abs=0.01)


def test_without_lighten_synthesis_only_measured_labels_are_lightened():
    """v6 read light Poisson points as blue: its synthesised items lightened to a few dozen points kept labels the
    synthesiser cannot realise. With scale.lighten_synthesis=false only other methods' items are drawn below the base."""
    from data_gen.pairs import make_pair

    def drawn(lighten: bool) -> list[tuple[str, float]]:
        settings = PairSettings.from_config(compose_config("pairs", [
            "map_size=32", "raster_size=32", "synthesis.points_per_ink=1000", "synthesis.iterations=2", "scale.share=1.0",
            "scale.points_per_ink=[100,10000]", "other_methods.share=0.5",
            f"scale.lighten_synthesis={str(lighten).lower()}"]))
        maker = build_maker(settings.dataset, settings.map_size, settings.palette)
        metas = [make_pair(settings, maker, item).meta[0] for item in range(24)]
        return [(meta["method"], meta["points_per_ink"] / settings.points_per_ink) for meta in metas if meta["n"]]

    fixed, old = drawn(False), drawn(True)
    assert all(ratio >= 1 for method, ratio in fixed if method == "synthesis")
    assert any(ratio < 1 for method, ratio in fixed if method != "synthesis")  # measured labels are still lightened
    assert any(ratio < 1 for method, ratio in old if method == "synthesis")  # what the option turns off
    assert scale_settings().key() == PairSettings.from_config(compose_config(
        "pairs", ["map_size=32", "scale.share=1.0", "scale.lighten_synthesis=true"])).key()  # v6's folder keeps its key


def test_without_sparse_lighten_synthesis_only_measured_labels_are_lightened():
    """The v5 recipe's sparse lightening (x0.03-0.4) gave synthesised items labels that a few dozen points cannot
    show (v6 and v6c read light Poisson points as bluish). With sparse.lighten_synthesis=false the synthesiser's
    items keep the maker's density; other methods' items (measured labels) are still lightened."""
    from data_gen.pairs import make_pair

    def items(lighten: bool) -> list[tuple[str, float, float]]:
        """(method, item's mean L, the maker's map's mean L) of each non-empty item, every map drawn lightened."""
        settings = PairSettings.from_config(compose_config("pairs", [
            "map_size=32", "raster_size=32", "synthesis.points_per_ink=3000", "synthesis.iterations=2", "sparse.share=1.0",
            "sparse.holes=0", "other_methods.share=0.5", f"sparse.lighten_synthesis={str(lighten).lower()}"]))
        maker = build_maker(settings.dataset, settings.map_size, settings.palette)
        rows = []
        for item in range(16):
            pair = make_pair(settings, maker, item)
            made = map_to_target(target_to_map(map_to_target(maker.make(item, np.random.default_rng([settings.seed, item])))))
            if pair.meta[0]["n"]:
                rows.append((pair.meta[0]["method"], float(pair.target[0][..., 0].mean()), float(made[..., 0].mean())))
        return rows

    fixed, old = items(False), items(True)
    assert any(method == "synthesis" for method, _, _ in fixed) and any(method != "synthesis" for method, _, _ in fixed)
    assert all(L == made for method, L, made in fixed if method == "synthesis")  # the maker's map, not lightened
    assert all(L > made for method, L, made in fixed if method != "synthesis")  # measured labels are still lightened
    assert all(L > made for method, L, made in old if method == "synthesis")  # what the option turns off
    assert PairSettings.from_config(compose_config("pairs", ["map_size=32", "sparse.share=0.25"])).key() == \
        PairSettings.from_config(compose_config("pairs", ["map_size=32", "sparse.share=0.25",
                                                          "sparse.lighten_synthesis=true"])).key()  # v5's folders keep their key


def test_clean_pairs_drops_exactly_the_lightened_synthesised_items(tmp_path):
    """A folder of the old rule (sparse.lighten_synthesis=true): the cleaned copy keeps other methods' items and the
    synthesised items whose maps were not lightened, found by replaying their draws; the manifest says what went."""
    from data_gen.clean_pairs import main
    from data_gen.shards import read_manifest

    generate(compose_config("pairs", [f"out_dir={tmp_path / 'old'}", "workers=1", "map_size=32", "raster_size=32",
                                      "synthesis.points_per_ink=3000", "synthesis.iterations=2", "num_items=16",
                                      "sparse.share=0.5", "sparse.holes=0", "other_methods.share=0.5"]))
    old = load_pairs(tmp_path / "old")
    assert main([str(tmp_path / "old"), str(tmp_path / "clean")]) == 0
    clean, record = load_pairs(tmp_path / "clean"), read_manifest(tmp_path / "clean")["cleaned"]
    settings = PairSettings.from_config(compose_config("pairs", ["map_size=32", "sparse.share=0.5", "sparse.holes=0"]))
    maker = build_maker(settings.dataset, settings.map_size, settings.palette)
    lightened = set()
    for item, meta, target in zip(old.item, old.meta, old.target, strict=True):  # the maker's own map: lighter when lightened
        made = maker.make(int(item), np.random.default_rng([0, int(item)]))
        if meta["method"] == "synthesis" and target[..., 0].mean() > map_to_target(target_to_map(map_to_target(made)))[..., 0].mean():
            lightened.add(int(item))
    assert lightened and set(record["dropped"]["sparse"]) == lightened and not record["dropped"]["unmatched"]
    assert sorted(clean.item.tolist()) == sorted(set(old.item.tolist()) - lightened)
    assert main([str(tmp_path / "old"), str(tmp_path / "clean")]) == 2  # never into a folder that has pairs (a user error: status 2)


def test_subset_pairs_keeps_the_first_shards_the_inked_items_and_a_seeded_draw(tmp_path):
    """data_gen.subset_pairs (the lineage's lattices-v7b-sub and light2-v7b-sub): first shards, then items of mean
    density >= --min-ink, then --keep of them drawn by the seed; the same call gives the same items."""
    from data_gen.shards import read_manifest
    from data_gen.subset_pairs import main, mean_ink

    generate(compose_config("pairs", [f"out_dir={tmp_path / 'src'}", "workers=1", "map_size=32", "raster_size=32", "chunk=4",
                                      "synthesis.points_per_ink=3000", "synthesis.iterations=2", "num_items=12",
                                      "sparse.share=0.5", "sparse.holes=0", "other_methods.share=1.0"]))
    source = load_pairs(tmp_path / "src")
    inks = {int(item): mean_ink(target) for item, target in zip(source.item, source.target, strict=True)}
    threshold = float(np.median(list(inks.values())))
    assert main([str(tmp_path / "src"), str(tmp_path / "first"), "--first-shards", "2"]) == 0
    assert sorted(load_pairs(tmp_path / "first").item.tolist()) == list(range(8))  # shards of 4 items: 0-3, 4-7
    assert main([str(tmp_path / "src"), str(tmp_path / "inked"), "--min-ink", str(threshold)]) == 0
    inked = sorted(load_pairs(tmp_path / "inked").item.tolist())
    assert inked == sorted(item for item, ink in inks.items() if ink >= threshold) and 0 < len(inked) < 12
    for name in ("a", "b"):
        assert main([str(tmp_path / "src"), str(tmp_path / name), "--min-ink", str(threshold), "--keep", "3", "--seed", "11"]) == 0
    drawn = sorted(load_pairs(tmp_path / "a").item.tolist())
    assert drawn == sorted(load_pairs(tmp_path / "b").item.tolist()) and len(drawn) == 3 and set(drawn) <= set(inked)
    assert read_manifest(tmp_path / "a")["subset"]["kept"] == 3
    assert main([str(tmp_path / "src"), str(tmp_path / "a")]) == 1  # never into a folder that has pairs

def lattice_angle(xy: np.ndarray, period: float) -> float:
    """Orientation (radians, modulo the lattice's rotational period) of the nearest-neighbour vectors of xy (k, 2)."""
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(xy).query(xy, k=2)
    delta = xy[nearest[:, 1]] - xy
    angles = np.mod(np.arctan2(delta[:, 1], delta[:, 0]), period) * (2 * np.pi / period)
    return float(np.mod(np.angle(np.mean(np.exp(1j * angles))), 2 * np.pi) * period / (2 * np.pi))


@pytest.mark.parametrize(("hexagonal", "period"), [(False, np.pi / 2), (True, np.pi / 3)])
def test_rotated_lattices_are_rotated_lattices(hexagonal, period):
    from scipy.spatial import cKDTree

    from data_gen.stipplers import r_max, rotated_lattice

    n = 900
    spacing = r_max(n, 1.0) if hexagonal else 1.0 / np.sqrt(n)
    angles = []
    for seed in range(6):
        xy = rotated_lattice(n, hexagonal, 0.0, np.random.default_rng(seed))
        assert abs(len(xy) - n) <= 0.05 * n and np.all((xy >= 0) & (xy < 1))
        distances, _ = cKDTree(xy).query(xy, k=2)
        np.testing.assert_allclose(distances[:, 1], spacing, rtol=1e-6)  # a perfect lattice without jitter
        angles.append(lattice_angle(xy, period))
    spread = np.ptp(np.sort(angles))
    assert spread > 0.3 * period  # six draws are not all at one orientation (the unrotated lattice would give 0)
    shifted = [rotated_lattice(n, hexagonal, 0.0, np.random.default_rng(seed))[:1] for seed in (0, 0)]
    np.testing.assert_array_equal(*shifted)  # deterministic per stream


@pytest.mark.parametrize("method", ["lattice_square", "lattice_hex", "lattice_square_jitter", "lattice_hex_jitter"])
def test_lattice_methods_follow_the_density_and_have_measured_labels(method):
    xy = METHODS[method](gradient(), 800, (1.0, 40 / 60), np.random.default_rng(2))
    assert abs(len(xy) - 800) <= 0.06 * 800
    assert np.sum(xy[:, 0] > 0.5) > 1.5 * np.sum(xy[:, 0] < 0.5)
    assert len(LABELS[method]) == 2 and LABELS[method][1] < -30  # measured blue-green side (bench/stippler_labels.json)


@pytest.mark.parametrize("method", ["lattice_square", "lattice_hex", "floyd_steinberg"])
def test_measured_labels_are_what_the_shipped_palette_decodes_at_any_rotation(method):
    palette = load_palette()
    decoded = [palette.locate(METHODS[method](np.full((64, 64), 0.4), 2048, (1.0, 1.0), np.random.default_rng(seed)))
               for seed in (5, 6, 7)]  # a lattice's rotation and offset come from the seed
    for colour in decoded:
        assert np.hypot(colour.a - LABELS[method][0], colour.b - LABELS[method][1]) < 6.0


def test_v6_generation_config_mixes_every_source_and_keeps_the_default_key():
    default = PairSettings.from_config(compose_config("pairs", []))
    v6 = PairSettings.from_config(compose_config("pairs", ["generation@_global_=v6"]))
    assert default.key() == PairSettings.from_config(compose_config("pairs", ["scale.points_per_ink=[1000,2000]"])).key()
    assert v6.scale["share"] > 0 and v6.textures["share"] > 0 and v6.other_methods["share"] > 0
    assert {"lattice_square", "lattice_hex", "jarvis", "bayer", "lloyd_few"} <= {k for k, w in v6.other_methods["methods"].items() if w}
    with pytest.raises(PatternshopError, match="frozen"):
        PairSettings.from_config(compose_config("pairs", ["generation@_global_=v6", "+other_methods.methods.capacity_voronoi=1.0"]))


@pytest.mark.parametrize("method", [name for name in METHODS if name.startswith("matern_")])
def test_matern_clusters_follow_the_density_cluster_and_read_their_measured_labels(method):
    xy = METHODS[method](gradient(), 800, (1.0, 40 / 60), np.random.default_rng(2))
    assert len(xy) == 800 and np.all((xy >= 0) & (xy <= (1.0, 40 / 60)))
    assert np.sum(xy[:, 0] > 0.5) > 1.5 * np.sum(xy[:, 0] < 0.5)
    uniform = METHODS[method](np.full((64, 64), 0.4), 2048, (1.0, 1.0), np.random.default_rng(4))
    nearest = np.sort(cKDTree(uniform).query(uniform, k=2)[0][:, 1])
    assert np.median(nearest) < 0.5 / np.sqrt(2048)  # clustered: nearer neighbours than Poisson's 0.5 mean spacing
    colour = load_palette().locate(uniform)
    assert np.hypot(colour.a - LABELS[method][0], colour.b - LABELS[method][1]) < 16.0  # spreads 1.0-9.3; presets 40-160 apart
