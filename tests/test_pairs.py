"""Training pairs (data_gen): the dataset readers on tiny stand-in folders, the pair generator
(shards, manifest, resumption, determinism, sharding, skipped sources), the point rasteriser,
the contact sheet and the command-line errors.

Everything is tiny (32 x 32 maps, a few hundred points, 20 synthesis iterations, one worker)
so the whole file runs in well under a minute on two busy cores.
"""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
import tifffile
from PIL import Image
from scipy.spatial import cKDTree

from data_gen import preview
from data_gen.makers import MAKERS, SourceError, build_maker
from data_gen.makers.faces import IMAGE_DIR, MASK_DIR
from data_gen.pairs import PairSettings, generate
from data_gen.pairs import main as pairs_main
from data_gen.provenance import compose_config
from data_gen.shards import MANIFEST, PARTS, list_shards, load_pairs, read_manifest, read_shard, shard_path, target_to_map
from synthesis.errors import PatternshopError
from synthesis.labmap import LabMap
from synthesis.palette import POPULATED_RADIUS, load_palette
from synthesis.raster import point_raster

SIZE = 32
POINTS_PER_INK = 400
TINY = ["chunk=2", f"map_size={SIZE}", f"raster_size={SIZE}", f"synthesis.points_per_ink={POINTS_PER_INK}",
        "synthesis.iterations=20", "workers=1"]


# --- helpers ---------------------------------------------------------------------
def grey_image(seed: int, size: int = 40) -> np.ndarray:
    """A (size, size) uint8 grey picture with plenty of ink: a gradient, a dark block and noise."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:size, 0:size]
    grey = 60 + 120 * cols / size + rng.uniform(-20, 20, (size, size))
    grey[size // 4 : size // 2, size // 4 : size // 2] = 25 + 10 * seed % 50
    return np.clip(grey, 0, 255).astype(np.uint8)


def save_grey(path: Path, seed: int, size: int = 40, **kwargs) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(grey_image(seed, size)).save(path, **kwargs)
    return path


def grey_density(grey: float) -> float:
    """Density 1 - L*/100 of an sRGB grey level 0..255."""
    return float(LabMap.from_srgb(np.full((1, 1, 3), grey / 255.0)).density()[0, 0])


def distinct_latents(lab_map: LabMap, mask: np.ndarray | None = None) -> np.ndarray:
    latent = lab_map.latent()
    values = latent.reshape(-1, 2) if mask is None else latent[mask]
    return np.unique(values, axis=0)


def populated_distance(latents: np.ndarray) -> np.ndarray:
    """Distance of latents (..., 2) to the shipped palette's nearest exemplar."""
    return cKDTree(load_palette().exemplar_z).query(np.asarray(latents, np.float64).reshape(-1, 2))[0]


def quoted(path: Path) -> str:
    return "'" + str(path) + "'"  # Hydra override value, whatever characters pytest puts in tmp paths


def pair_config(root: Path, out: Path, *extra: str, dataset: str = "folder"):
    return compose_config("pairs", [f"dataset={dataset}", f"dataset.root={quoted(root)}", f"out_dir={quoted(out)}", *TINY, *extra])


def folder_of_images(folder: Path, count: int) -> Path:
    for i in range(count):
        save_grey(folder / f"img{i:02d}.png", i)
    return folder


def shard_bytes(out: Path) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in list_shards(out)}


def check_pairs(pairs, raster_size: int = SIZE, map_size: int = SIZE) -> None:
    """The invariants of a shard: shapes, offsets, point counts, and the raster being point_raster of the points."""
    k = len(pairs)
    assert pairs.raster.shape == (k, raster_size, raster_size) and pairs.raster.dtype == np.float16
    assert pairs.target.shape == (k, map_size, map_size, 3) and pairs.target.dtype == np.uint8
    assert pairs.offsets.shape == (k + 1,) and pairs.offsets[0] == 0 and pairs.offsets[-1] == len(pairs.points)
    assert len(pairs.meta) == k
    assert np.all((pairs.points >= 0) & (pairs.points <= 1))
    for j in range(k):
        meta, points = pairs.meta[j], pairs.points_of(j)
        assert meta["item"] == int(pairs.item[j])
        assert len(points) == meta["n"] == round(POINTS_PER_INK * float(target_to_map(pairs.target[j]).density().mean()))
        np.testing.assert_array_equal(pairs.raster[j], point_raster(points, raster_size).astype(np.float16))
        # each point adds unit mass; sums are clipped at 1 per pixel (clustered patterns lose some)
        assert 0 < float(pairs.raster[j].astype(np.float64).sum()) <= meta["n"] * 1.001 + 0.01


def same_pairs(first, second) -> None:
    """Equal arrays and metadata, but for the synthesis wall time."""
    for name in ("item", "raster", "target", "points", "offsets"):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name), err_msg=name)
    strip = lambda metas: [{k: v for k, v in m.items() if k != "seconds"} for m in metas]  # noqa: E731
    assert strip(first.meta) == strip(second.meta)
    assert first.skipped == second.skipped


# --- faces (CelebAMask-HQ) --------------------------------------------------------
FACE_IDS = (0, 5, 2001)  # 5 has no masks; 2001's masks live in folder 1 (id // 2000)


def make_faces(root: Path) -> Path:
    """64 x 64 grey 'photos' (left half grey 50, right half grey 200) with 64 x 64 masks for some ids.

    Masks (map pixels at size 32 = mask pixels / 2): skin = rows 8-23, cols 8-23; hair = rows 0-11
    (overlapping the top of the skin: hair is listed later, so it wins there); the rest background.
    """
    photo = np.full((64, 64), 200, np.uint8)
    photo[:, :32] = 50
    for image_id in FACE_IDS:
        path = root / IMAGE_DIR / f"{image_id}.jpg"
        path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(photo).save(path, quality=100)
    skin = np.zeros((64, 64), np.uint8)
    skin[16:48, 16:48] = 255
    hair = np.zeros((64, 64), np.uint8)
    hair[:24, :] = 255
    for image_id in (0, 2001):
        folder = root / MASK_DIR / str(image_id // 2000)
        folder.mkdir(parents=True, exist_ok=True)
        Image.fromarray(skin).save(folder / f"{image_id:05d}_skin.png")
        Image.fromarray(hair).save(folder / f"{image_id:05d}_hair.png")
    (root / MASK_DIR / "0" / "notes.txt").write_text("not a mask")
    return root


def test_faces_two_items_per_image_uniform_and_per_segment(tmp_path):
    maker = build_maker({"name": "faces", "root": str(make_faces(tmp_path))}, SIZE)
    assert len(maker) == 2 * len(FACE_IDS)
    assert "(uniform)" in maker.source(0) and "(segments)" in maker.source(1)
    assert "2001.jpg" in maker.source(4)  # images sorted by number, not by name

    uniform = maker.make(0, np.random.default_rng(0))
    assert uniform.lab.shape == (SIZE, SIZE, 3)
    assert len(distinct_latents(uniform)) == 1

    # density = 1 - L*/100 of the grey photo: dark (grey 50) left half, light (grey 200) right half
    density = uniform.density()
    np.testing.assert_allclose(density[:, 2:14], grey_density(50), atol=0.01)
    np.testing.assert_allclose(density[:, 18:30], grey_density(200), atol=0.01)
    assert density[:, :16].mean() > density[:, 16:].mean() + 0.3

    segments = maker.make(1, np.random.default_rng(0))
    np.testing.assert_allclose(segments.density(), density, atol=1e-5)  # same photo, same density
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    regions = {
        "hair": rows < 12,
        "skin": (rows >= 12) & (rows < 24) & (cols >= 8) & (cols < 24),
        "background": (rows >= 24) | ((rows >= 12) & ((cols < 8) | (cols >= 24))),
    }
    assert sum(mask.sum() for mask in regions.values()) == SIZE * SIZE
    latents = {}
    for name, mask in regions.items():
        values = distinct_latents(segments, mask)
        assert len(values) == 1, f"{name}: {len(values)} latents in one segment"
        latents[name] = values[0]
    assert len(np.unique(np.stack(list(latents.values())), axis=0)) == 3  # skin, hair, background differ
    assert len(distinct_latents(segments)) == 3
    assert np.all(populated_distance(segments.latent()) <= POPULATED_RADIUS + 1e-4)


def test_faces_image_without_masks_loses_only_its_segment_item(tmp_path):
    maker = build_maker({"name": "faces", "root": str(make_faces(tmp_path))}, SIZE)
    assert "5.jpg" in maker.source(2)
    assert len(distinct_latents(maker.make(2, np.random.default_rng(1)))) == 1  # uniform item of id 5 is fine
    with pytest.raises(SourceError, match="no masks"):
        maker.make(3, np.random.default_rng(1))
    segments = maker.make(5, np.random.default_rng(1))  # id 2001, masks under folder 1
    assert len(distinct_latents(segments)) == 3


def test_faces_layout_errors(tmp_path):
    with pytest.raises(PatternshopError, match="dataset.root"):
        build_maker({"name": "faces", "root": None}, SIZE)
    with pytest.raises(SourceError, match=IMAGE_DIR):
        build_maker({"name": "faces", "root": str(tmp_path)}, SIZE)


def test_faces_maker_is_deterministic_given_the_rng(tmp_path):
    maker = build_maker({"name": "faces", "root": str(make_faces(tmp_path))}, SIZE)
    first, again = maker.make(1, np.random.default_rng(7)), maker.make(1, np.random.default_rng(7))
    np.testing.assert_array_equal(first.lab, again.lab)
    other = maker.make(1, np.random.default_rng(8))
    assert not np.array_equal(first.lab, other.lab)


# --- animals (AFHQ) --------------------------------------------------------------
def test_animals_reads_splits_and_classes_with_uniform_chroma(tmp_path):
    save_grey(tmp_path / "train" / "cat" / "a.png", 1)
    save_grey(tmp_path / "train" / "cat" / "b.png", 2)
    save_grey(tmp_path / "train" / "dog" / "c.png", 3)
    save_grey(tmp_path / "val" / "wild" / "d.png", 4)
    save_grey(tmp_path / "train" / "other" / "e.png", 5)  # not an AFHQ class
    save_grey(tmp_path / "test" / "cat" / "f.png", 6)  # not a chosen split
    (tmp_path / "train" / "cat" / "readme.txt").write_text("x")

    maker = build_maker({"name": "animals", "root": str(tmp_path), "splits": ["train", "val"],
                         "classes": ["cat", "dog", "wild"]}, SIZE)
    assert len(maker) == 4
    names = [Path(maker.source(i)).relative_to(tmp_path).as_posix() for i in range(len(maker))]
    assert names == ["train/cat/a.png", "train/cat/b.png", "train/dog/c.png", "val/wild/d.png"]
    for i in range(len(maker)):
        lab_map = maker.make(i, np.random.default_rng(i))
        assert lab_map.lab.shape == (SIZE, SIZE, 3)
        assert len(distinct_latents(lab_map)) == 1

    only_cats = build_maker({"name": "animals", "root": str(tmp_path), "splits": ["train"], "classes": ["cat"]}, SIZE)
    assert len(only_cats) == 2
    with pytest.raises(SourceError, match="AFHQ"):
        build_maker({"name": "animals", "root": str(tmp_path / "train" / "cat")}, SIZE)


# --- churches and folder ----------------------------------------------------------
def test_churches_and_folder_read_image_folders(tmp_path):
    save_grey(tmp_path / "b.webp", 1)
    save_grey(tmp_path / "a.jpg", 2)
    save_grey(tmp_path / "sub" / "deeper" / "c.PNG", 3)  # suffixes match case-insensitively
    (tmp_path / "sub" / "notes.txt").write_text("not an image")

    folder = build_maker({"name": "folder", "root": str(tmp_path), "gaussian_fraction": 0.0}, SIZE)
    assert [Path(folder.source(i)).relative_to(tmp_path).as_posix() for i in range(len(folder))] == \
        ["a.jpg", "b.webp", "sub/deeper/c.PNG"]
    churches = build_maker({"name": "churches", "root": str(tmp_path)}, SIZE)
    assert len(churches) == 3

    for maker in (folder, churches):
        lab_map = maker.make(0, np.random.default_rng(3))
        assert len(distinct_latents(lab_map)) == 1
        rgb = np.asarray(Image.open(tmp_path / "a.jpg").convert("RGB").resize((SIZE, SIZE), Image.Resampling.BOX))
        expected = LabMap.from_srgb(rgb / 255.0).density()
        np.testing.assert_allclose(lab_map.density(), expected, atol=2e-3)

    gaussian = build_maker({"name": "folder", "root": str(tmp_path), "gaussian_fraction": 1.0}, SIZE)
    field = gaussian.make(0, np.random.default_rng(3))
    assert len(distinct_latents(field)) > 1  # a smooth field, not one latent
    assert np.all(populated_distance(field.latent()) <= POPULATED_RADIUS + 1e-4)


def test_folder_errors(tmp_path):
    with pytest.raises(PatternshopError, match="not a folder"):
        build_maker({"name": "folder", "root": str(tmp_path / "missing")}, SIZE)
    with pytest.raises(SourceError, match="no images"):
        build_maker({"name": "folder", "root": str(tmp_path)}, SIZE)
    with pytest.raises(PatternshopError, match="unknown dataset"):
        build_maker({"name": "pictures", "root": str(tmp_path)}, SIZE)


def test_folder_skips_white_and_unreadable_images(tmp_path):
    Image.fromarray(np.full((40, 40), 255, np.uint8)).save(tmp_path / "a_white.png")
    (tmp_path / "b_garbage.png").write_bytes(b"\x89PNG not really" + bytes(range(256)))
    maker = build_maker({"name": "folder", "root": str(tmp_path)}, SIZE)
    with pytest.raises(SourceError, match="nearly white"):
        maker.make(0, np.random.default_rng(0))
    with pytest.raises(SourceError, match="unreadable image"):
        maker.make(1, np.random.default_rng(0))


# --- treecover ---------------------------------------------------------------------
def test_treecover_tiles_density_and_missing_tiles(tmp_path):
    tile = 16
    cover = np.zeros((40, 36), np.uint8)  # 2 x 2 whole tiles; the last 8 rows and 4 columns are cut off
    cover[:16, :16] = (np.arange(256).reshape(16, 16) * 100 // 255).astype(np.uint8)  # 0..100 percent
    cover[3, 5] = 254  # a few missing pixels (2 / 256 < 5 %): kept, as density 0
    cover[9, 11] = 255
    cover[:16, 16:32] = 255  # tile (0, 16): all missing
    cover[16:32, :16] = 60
    cover[16:32, :16][:10, :] = 254  # tile (16, 0): 10 / 16 rows outside the area
    cover[16:32, 16:32] = 0  # tile (16, 16): no trees at all
    tifffile.imwrite(tmp_path / "a.tif", cover)
    second = np.full((20, 20), 80, np.uint8)  # one tile
    (tmp_path / "sub").mkdir()
    tifffile.imwrite(tmp_path / "sub" / "b.tiff", second)
    (tmp_path / "broken.tif").write_bytes(b"II*\x00garbage")  # unreadable: loses its own tiles only
    (tmp_path / "notes.txt").write_text("not a raster")

    config = {"name": "treecover", "root": str(tmp_path), "tile": tile, "max_missing": 0.05,
              "missing_values": [254, 255], "gaussian_fraction": 0.0}
    maker = build_maker(config, tile)
    assert len(maker) == 5
    assert len(maker.unreadable) == 1 and "broken.tif" in maker.unreadable[0]
    assert "row 0, column 16" in maker.source(1) and "b.tiff" in maker.source(4)

    lab_map = maker.make(0, np.random.default_rng(0))
    expected = cover[:16, :16].astype(np.float64) / 100.0
    expected[3, 5] = expected[9, 11] = 0.0
    np.testing.assert_allclose(lab_map.density(), expected, atol=1e-5)
    assert len(distinct_latents(lab_map)) == 1  # gaussian_fraction 0: uniform chroma

    with pytest.raises(SourceError, match="missing"):
        maker.make(1, np.random.default_rng(0))
    with pytest.raises(SourceError, match="missing"):
        maker.make(2, np.random.default_rng(0))
    with pytest.raises(SourceError, match="nearly white"):
        maker.make(3, np.random.default_rng(0))
    np.testing.assert_allclose(maker.make(4, np.random.default_rng(0)).density(), 0.8, atol=1e-5)

    resized = build_maker(config, 8)  # tiles are resampled to the map size
    small = resized.make(0, np.random.default_rng(0))
    assert small.lab.shape == (8, 8, 3)
    np.testing.assert_allclose(small.density().mean(), expected.mean(), atol=1e-3)


def test_treecover_without_tiles_is_an_error(tmp_path):
    tifffile.imwrite(tmp_path / "small.tif", np.full((10, 10), 50, np.uint8))
    with pytest.raises(SourceError, match="no 16 x 16 tiles"):
        build_maker({"name": "treecover", "root": str(tmp_path), "tile": 16}, 16)


# --- procedural --------------------------------------------------------------------
def procedural_item(maker, index: int, seed: int):
    try:
        return maker.make(index, np.random.default_rng([seed, index])).lab
    except SourceError as exc:
        return str(exc)


def test_procedural_is_deterministic_and_in_the_populated_region():
    maker = build_maker({"name": "procedural", "items": 7}, SIZE)
    assert len(maker) == 7 and not maker.finite
    maps = []
    for index in range(6):
        first, again = procedural_item(maker, index, 0), procedural_item(maker, index, 0)
        if isinstance(first, str):
            assert first == again
            continue
        np.testing.assert_array_equal(first, again)
        assert first.shape == (SIZE, SIZE, 3)
        maps.append(first)
        other = procedural_item(maker, index, 1)
        assert isinstance(other, str) or not np.array_equal(first, other)
    assert len(maps) >= 4
    assert len({m.tobytes() for m in maps}) == len(maps)  # every item its own picture
    latents = np.concatenate([LabMap(m).latent().reshape(-1, 2) for m in maps])
    assert np.all(populated_distance(latents) <= POPULATED_RADIUS + 1e-4)
    assert all(LabMap(m).density().mean() >= 0.02 for m in maps)


def test_procedural_chroma_modes_and_unknown_kinds():
    uniform = build_maker({"name": "procedural", "chroma": {"uniform": 1.0}}, SIZE)
    for index in range(3):
        lab = procedural_item(uniform, index, 0)
        if not isinstance(lab, str):
            assert len(distinct_latents(LabMap(lab))) == 1
    segments = build_maker({"name": "procedural", "kinds": {"voronoi": 1.0}, "chroma": {"segments": 1.0}}, SIZE)
    lab = procedural_item(segments, 0, 0)
    assert not isinstance(lab, str) and len(distinct_latents(LabMap(lab))) > 1
    with pytest.raises(PatternshopError, match="unknown kinds"):
        build_maker({"name": "procedural", "kinds": {"clouds": 1.0}}, SIZE)


def test_every_dataset_config_names_a_maker():
    from omegaconf import OmegaConf

    for name in MAKERS:
        config = OmegaConf.to_container(compose_config("pairs", [f"dataset={name}"]).dataset)
        assert config["name"] == name


# --- pair generation ----------------------------------------------------------------
def test_generate_writes_shards_and_manifest_and_resumes(tmp_path):
    root, out = folder_of_images(tmp_path / "images", 5), tmp_path / "pairs"
    cfg = pair_config(root, out, "num_items=7")  # more than the folder holds: capped at 5
    summary = generate(cfg)
    assert summary["made_now"] == 5 and summary["skipped_now"] == []
    assert summary["pairs_in_folder"] == 5 and summary["skipped_in_folder"] == 0
    assert [path.name for path in list_shards(out)] == ["pairs-00000.npz", "pairs-00001.npz", "pairs-00002.npz"]
    assert not list((out / PARTS).iterdir())  # parts are merged into shards and deleted

    manifest = read_manifest(out)
    assert manifest["dataset"] == "folder" and manifest["pairs"] == 5 and manifest["skipped"] == []
    assert [shard["pairs"] for shard in manifest["shards"]] == [2, 2, 1]
    assert manifest["config_key"] == PairSettings.from_config(cfg).key()
    assert manifest["raster"] == {"function": "synthesis.raster.point_raster", "size": SIZE}
    assert manifest["points"] == sum(m["n"] for m in load_pairs(out).meta)

    pairs = load_pairs(out)
    np.testing.assert_array_equal(pairs.item, np.arange(5))
    assert [Path(m["source"]).name for m in pairs.meta] == [f"img{i:02d}.png" for i in range(5)]
    check_pairs(pairs)
    for j, shard in enumerate(list_shards(out)):  # each shard holds its own chunk of items
        np.testing.assert_array_equal(read_shard(shard).item, np.arange(2 * j, min(2 * j + 2, 5)))

    before = shard_bytes(out)
    again = generate(cfg)
    assert again["made_now"] == 0 and again["skipped_now"] == [] and again["pairs_in_folder"] == 5
    assert shard_bytes(out) == before


def test_deleted_shard_is_remade_identically(tmp_path):
    root, out = folder_of_images(tmp_path / "images", 4), tmp_path / "pairs"
    cfg = pair_config(root, out)
    assert generate(cfg)["made_now"] == 4
    before = shard_bytes(out)
    first = read_shard(shard_path(out, 0))

    shard_path(out, 0).unlink()
    summary = generate(cfg)
    assert summary["made_now"] == 2 and summary["pairs_in_folder"] == 4
    same_pairs(read_shard(shard_path(out, 0)), first)
    assert shard_bytes(out)["pairs-00001.npz"] == before["pairs-00001.npz"]  # untouched


def test_sharded_runs_make_only_their_shards_and_match_one_run(tmp_path):
    root = folder_of_images(tmp_path / "images", 5)
    whole, split = tmp_path / "whole", tmp_path / "split"
    generate(pair_config(root, whole))

    summary = generate(pair_config(root, split, "shard=1", "num_shards=2"))
    assert summary["shard"] == "1/2" and summary["made_now"] == 2
    assert [path.name for path in list_shards(split)] == ["pairs-00001.npz"]
    assert read_manifest(split)["pairs"] == 2
    np.testing.assert_array_equal(read_shard(shard_path(split, 1)).item, [2, 3])

    summary = generate(pair_config(root, split, "shard=0", "num_shards=2"))
    assert summary["made_now"] == 3 and summary["pairs_in_folder"] == 5  # the manifest counts every shard present
    assert [path.name for path in list_shards(split)] == [path.name for path in list_shards(whole)]
    same_pairs(load_pairs(split), load_pairs(whole))  # item i's pair does not depend on the sharding

    with pytest.raises(PatternshopError, match="shard"):
        generate(pair_config(root, split, "shard=2", "num_shards=2"))


def test_changed_settings_into_the_same_folder_are_refused(tmp_path):
    root, out = folder_of_images(tmp_path / "images", 2), tmp_path / "pairs"
    generate(pair_config(root, out))
    before = shard_bytes(out)
    for change in ("seed=1", "map_size=48", "synthesis.points_per_ink=500", "dataset.gaussian_fraction=0.5"):
        with pytest.raises(PatternshopError, match="other settings"):
            generate(pair_config(root, out, change))
    assert shard_bytes(out) == before
    assert generate(pair_config(root, out, "num_items=1"))["made_now"] == 0  # how many is not a setting


def test_config_key_ignores_procedural_item_count_only():
    key = lambda *extra: PairSettings.from_config(compose_config("pairs", [*TINY, *extra])).key()  # noqa: E731
    assert key("dataset.items=10") == key("dataset.items=20") == key("workers=2", "num_items=3", "out_dir=x")
    assert len({key(), key("seed=1"), key("raster_size=64"), key("chunk=4"), key("dataset.chroma.uniform=1.0")}) == 5


def test_procedural_generation_makes_num_items(tmp_path):
    out = tmp_path / "pairs"
    cfg = compose_config("pairs", ["dataset=procedural", f"out_dir={quoted(out)}", "num_items=3", *TINY])
    summary = generate(cfg)
    assert summary["dataset"] == "procedural"
    assert summary["made_now"] + len(summary["skipped_now"]) == 3
    pairs = load_pairs(out)
    assert len(pairs) == summary["made_now"] >= 1
    check_pairs(pairs)
    with pytest.raises(PatternshopError, match="num_items"):
        generate(compose_config("pairs", ["dataset=procedural", f"out_dir={quoted(out)}", "num_items=0", *TINY]))


def truncated_jpeg(path: Path) -> None:
    buffer = io.BytesIO()
    Image.fromarray(grey_image(9, 64)).save(buffer, format="JPEG", quality=90)
    path.write_bytes(buffer.getvalue()[: len(buffer.getvalue()) // 2])


@pytest.mark.parametrize("names", [
    ["a.png", "b.png", "c_garbage.png", "d_truncated.jpg", "e.png"],  # both bad in chunk 1: a shard of skipped items only
    ["a.png", "b_garbage.png", "c.png", "d_truncated.jpg", "e.png"],  # one bad item in each of two chunks
], ids=["same_chunk", "two_chunks"])
def test_corrupt_images_are_skipped_and_recorded(tmp_path, names):
    root, out = tmp_path / "images", tmp_path / "pairs"
    root.mkdir()
    for seed, name in enumerate(names):
        if "garbage" in name:
            (root / name).write_bytes(b"this is no png" * 10)
        elif "truncated" in name:
            truncated_jpeg(root / name)
        else:
            save_grey(root / name, seed)
    bad = {name for name in names if "garbage" in name or "truncated" in name}
    summary = generate(pair_config(root, out))
    assert summary["made_now"] == 3 and summary["pairs_in_folder"] == 3 and summary["skipped_in_folder"] == 2
    assert len(summary["skipped_now"]) == 2
    assert all("unreadable image" in reason for reason in summary["skipped_now"])
    assert {name for name in bad for reason in summary["skipped_now"] if name in reason} == bad

    manifest = read_manifest(out)
    assert {Path(entry["source"]).name for entry in manifest["skipped"]} == bad
    assert all("unreadable image" in entry["reason"] for entry in manifest["skipped"])
    assert sorted(entry["item"] for entry in manifest["skipped"]) == [i for i, name in enumerate(names) if name in bad]
    assert sum(shard["skipped"] for shard in manifest["shards"]) == 2

    pairs = load_pairs(out)  # every shard loads, even one holding only skipped items
    assert len(pairs) == 3 and not {Path(m["source"]).name for m in pairs.meta} & bad
    check_pairs(pairs)

    again = generate(pair_config(root, out))  # skipped sources are not retried
    assert again["made_now"] == 0 and again["skipped_now"] == [] and again["skipped_in_folder"] == 2


# --- rasteriser ----------------------------------------------------------------------
def test_point_raster_shape_range_and_mass():
    size = 32
    rng = np.random.default_rng(0)
    cells = np.stack(np.meshgrid(np.arange(2, size - 3, 3), np.arange(2, size - 3, 3)), -1).reshape(-1, 2)
    xy = (cells + 0.5 + rng.random(cells.shape)) / size  # 2 x 2 footprints apart: nothing clipped
    raster = point_raster(xy, size)
    assert raster.shape == (size, size) and raster.dtype == np.float32
    assert raster.min() >= 0 and raster.max() <= 1
    np.testing.assert_allclose(raster.sum(), len(xy), rtol=1e-5)

    centre = point_raster(np.array([[(5 + 0.5) / size, (9 + 0.5) / size]]), size)  # x -> column, y -> row
    assert centre[9, 5] == pytest.approx(1.0) and centre.sum() == pytest.approx(1.0)
    half = point_raster(np.array([[6.0 / size, 9.5 / size]]), size)  # halfway between columns 5 and 6
    np.testing.assert_allclose([half[9, 5], half[9, 6]], [0.5, 0.5], atol=1e-6)

    np.testing.assert_array_equal(point_raster(np.zeros((0, 2)), size), np.zeros((size, size), np.float32))
    crowded = point_raster(np.full((50, 2), 0.5), size)
    assert crowded.max() == 1.0 and crowded.sum() <= 4.0  # sums are clipped to [0, 1]


def test_point_raster_clamps_outside_points_and_checks_size():
    size = 8
    raster = point_raster(np.array([[-0.5, 2.0], [1.5, -3.0], [0.0, 0.0], [1.0, 1.0]]), size)
    expected = np.zeros((size, size), np.float32)
    expected[size - 1, 0] = expected[0, size - 1] = expected[0, 0] = expected[size - 1, size - 1] = 1.0
    np.testing.assert_allclose(raster, expected, atol=1e-6)
    assert point_raster(np.array([0.5, 0.5]), 2).shape == (2, 2)  # a single (2,) point is accepted
    for bad in (1, 0, -4):
        with pytest.raises(ValueError, match="at least 2"):
            point_raster(np.zeros((3, 2)), bad)


# --- contact sheet -------------------------------------------------------------------
@pytest.fixture(scope="module")
def pair_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("sheet")
    out = tmp / "pairs"
    generate(pair_config(folder_of_images(tmp / "images", 3), out))
    return out


def test_contact_sheet_writes_a_png_of_the_expected_size(pair_dir, tmp_path, capsys):
    output = tmp_path / "sheet.png"
    tile, columns = 16, 2
    assert preview.main([str(pair_dir), str(output), "--tile", str(tile), "--columns", str(columns)]) == 0
    assert "wrote" in capsys.readouterr().out
    rows = 2  # 3 pairs in 2 columns
    width = columns * (2 * tile + preview.GAP) + (columns + 1) * preview.GAP
    height = rows * (tile + preview.LABEL_HEIGHT) + (rows + 1) * preview.GAP
    with Image.open(output) as sheet:
        assert sheet.format == "PNG" and sheet.mode == "RGB" and sheet.size == (width, height)
        pixels = np.asarray(sheet)
    x, y = preview.GAP + tile + preview.GAP, preview.GAP  # first pair's dots panel
    assert pixels[y : y + tile, x : x + tile].min() < 128  # dark dots on white
    assert np.all(pixels[-preview.GAP :] == 255)  # white margin below the last row

    one = tmp_path / "one.png"
    assert preview.main([str(pair_dir), str(one), "--count", "1", "--columns", "1", "--tile", "8"]) == 0
    with Image.open(one) as sheet:
        assert sheet.size == (2 * 8 + 3 * preview.GAP, 8 + preview.LABEL_HEIGHT + 2 * preview.GAP)


@pytest.mark.parametrize("case", ["not_png", "empty_folder", "bad_count"])
def test_contact_sheet_errors_are_one_line(pair_dir, tmp_path, capsys, case):
    output = tmp_path / ("sheet.jpg" if case == "not_png" else "sheet.png")
    folder = tmp_path / "empty" if case == "empty_folder" else pair_dir
    folder.mkdir(exist_ok=True)
    extra = ["--count", "0"] if case == "bad_count" else []
    assert preview.main([str(folder), str(output), *extra]) == 2
    err = capsys.readouterr().err
    assert re.match(r"(python -m )?data_gen\.preview: error: \S", err) and err.count("\n") == 1, err
    assert not output.exists()


# --- command line --------------------------------------------------------------------
@pytest.mark.parametrize("args", [
    ["dataset=no_such_dataset"],
    ["dataset=folder"],
    ["dataset=faces", "dataset.root=/no/such/folder"],
    ["dataset.name=no_such_maker"],
    ["no_such_setting=1"],
    ["map_size=big"],
])
def test_pairs_command_errors_are_one_line(args, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the default out_dir is relative: nothing may land in the checkout
    assert pairs_main([*TINY, "num_items=2", *args]) == 2  # tiny settings first: the case's own override wins
    captured = capsys.readouterr()
    assert re.match(r"(python -m )?data_gen\.pairs: error: \S", captured.err) and captured.err.count("\n") == 1, captured.err
    assert captured.out == ""
    assert not (tmp_path / "data").exists()


def test_pairs_command_prints_the_summary(tmp_path, capsys):
    root, out = folder_of_images(tmp_path / "images", 2), tmp_path / "pairs"
    assert pairs_main(["dataset=folder", f"dataset.root={quoted(root)}", f"out_dir={quoted(out)}", *TINY]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["made_now"] == 2 and summary["pairs_in_folder"] == 2
    assert (out / MANIFEST).is_file()


# --- other methods' points (issue 14) ---------------------------------------------------------
def test_other_methods_make_labelled_pairs(tmp_path):
    """share=1: every item's points come from a stippler of data_gen.stipplers, its a,b are the method's preset."""
    from data_gen.stipplers import LABELS
    from synthesis.palette import load_palette
    from synthesis.raster import point_raster

    folder = tmp_path / "other"
    generate(compose_config("pairs", [f"out_dir={folder}", "num_items=5", "workers=1", "map_size=64", "raster_size=64",
                                      "synthesis.points_per_ink=1500", "other_methods.share=1.0"]))
    pairs = load_pairs(folder)
    presets = load_palette().preset_ab()
    methods = []
    for k, meta in enumerate(pairs.meta):
        method = meta["method"]
        methods.append(method)
        a, b = presets[LABELS[method]]
        assert np.all(pairs.target[k][..., 1] == round(a) + 128) and np.all(pairs.target[k][..., 2] == round(b) + 128)
        assert len(pairs.points_of(k)) == meta["n"] > 100
        np.testing.assert_allclose(pairs.raster[k], point_raster(pairs.points_of(k), 64), atol=1e-3)
    assert len(set(methods)) >= 2


def test_other_methods_share_zero_keeps_items_and_keys():
    def settings(*overrides):
        return PairSettings.from_config(compose_config("pairs", ["map_size=64", *overrides]))

    assert settings().key() == settings("other_methods.methods={random: 2.0}").key() == settings("sparse.holes=5").key()
    assert settings().key() != settings("sparse.empty_share=0.1").key()
    assert settings().key() == settings("dense.scale=[0.1,0.2]").key() != settings("dense.share=0.5").key()
    assert settings().key() != settings("other_methods.share=0.5").key()
    with pytest.raises(PatternshopError, match="unknown other_methods.methods"):
        settings("other_methods.share=0.5", "+other_methods.methods.voronoi=1")
    with pytest.raises(PatternshopError, match=r"share must be in \[0, 1\]"):
        settings("other_methods.share=2")


def test_sparse_items_are_light_holed_or_empty(tmp_path):
    """sparse.share=1 lightens every map (density x 0.03-0.4, holes); empty_share=0.5 empties about half of the items."""
    base = ["workers=1", "map_size=64", "raster_size=64", "synthesis.points_per_ink=1500", "synthesis.iterations=10",
            "num_items=6", "sparse.holes=2"]
    generate(compose_config("pairs", [f"out_dir={tmp_path / 'full'}", *base]))
    generate(compose_config("pairs", [f"out_dir={tmp_path / 'light'}", *base, "sparse.share=1.0"]))
    generate(compose_config("pairs", [f"out_dir={tmp_path / 'empty'}", *base, "sparse.empty_share=0.5"]))
    full, light, empty = (load_pairs(tmp_path / name) for name in ("full", "light", "empty"))
    full_ink = {int(i): 1 - t[..., 0].mean() / 255 for i, t in zip(full.item, full.target, strict=True)}
    for i, t in zip(light.item, light.target, strict=True):  # same maps, scaled down (0.4 at most, 8-bit rounding)
        assert 1 - t[..., 0].mean() / 255 <= 0.4 * full_ink[int(i)] + 0.01
    emptied = [k for k, meta in enumerate(empty.meta) if meta["method"] == "empty"]
    assert 1 <= len(emptied) <= 5
    for k in emptied:
        assert len(empty.points_of(k)) == 0 and not empty.raster[k].any() and np.all(empty.target[k][..., 0] == 255)
    with pytest.raises(PatternshopError, match="sparse.scale"):
        PairSettings.from_config(compose_config("pairs", ["sparse.share=0.5", "sparse.scale=[0.5,0.1]"]))


def test_dense_items_are_darkened_towards_full_ink(tmp_path):
    """dense.share=1 darkens every map: 1 - density x 0.05-0.5, so each item holds at least half as much ink again."""
    base = ["workers=1", "map_size=64", "raster_size=64", "synthesis.points_per_ink=1500", "num_items=4",
            "other_methods.share=1.0"]
    generate(compose_config("pairs", [f"out_dir={tmp_path / 'plain'}", *base]))
    generate(compose_config("pairs", [f"out_dir={tmp_path / 'dark'}", *base, "dense.share=1.0"]))
    plain, dark = load_pairs(tmp_path / "plain"), load_pairs(tmp_path / "dark")
    light_of = {int(i): t[..., 0].astype(float) / 255 for i, t in zip(plain.item, plain.target, strict=True)}
    assert len(dark.item) == 4
    for i, t in zip(dark.item, dark.target, strict=True):  # lightness x 0.05-0.5 (8-bit rounding)
        assert t[..., 0].mean() / 255 <= 0.5 * light_of[int(i)].mean() + 0.01
    with pytest.raises(PatternshopError, match="dense.scale"):
        PairSettings.from_config(compose_config("pairs", ["dense.share=0.5", "dense.scale=[0.5,0.1]"]))
