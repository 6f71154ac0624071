"""Start-up (issue 27): the synthesis path imports only what it needs and reads only the palette tables it uses.

Nothing here is timed: ``bench/bench_speed.py`` measures the start-up (its start-up section).
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import zipfile
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from helpers import fresh_python_lines
from synthesis.analysis import coincident_points
from synthesis.errors import PatternshopError
from synthesis.labmap import LabMap
from synthesis.palette import DEFAULT_PALETTE, Palette
from synthesis.pcf import r_max
from synthesis.points import PointSet

ROOT = Path(__file__).resolve().parent.parent
HEAVY_MODULES = ("torch", "matplotlib", "sklearn")  # decoding, plotting and training only
# the palette arrays synthesis reads; the exemplars' positions for the nearest-neighbour term's bounds, whose values
# come from the table beside the asset (palette_neighbours.npz), not measured on the exemplars' points at start-up
SYNTHESIS_TABLES = {"radii", "lut", "dispersion_lut", "exemplar_z"}
shipped = pytest.mark.skipif(not DEFAULT_PALETTE.exists(), reason="no shipped palette asset")


@shipped
def test_synthesis_path_imports_no_torch_matplotlib_or_sklearn(tmp_path):
    code = ("import sys\n"
            "from patternshop.cli import main\n"
            f"status = main(['synthesize', {str(ROOT / 'examples' / 'logo.tif')!r}, {str(tmp_path / 'p.txt')!r},"
            " '--points', '300', '--iterations', '2', '--no-progress'])\n"
            "import patternshop as ps\n"
            "ps.synthesize(ps.uniform_map(32, density=0.5, correlation='red'), points=300, iterations=2)\n"
            f"print(status, sorted(m for m in {HEAVY_MODULES!r} if m in sys.modules))\n")
    assert fresh_python_lines(code)[-1] == "0 []"


@shipped
def test_synthesis_reads_only_the_palette_tables_it_uses():
    from synthesis.synthesize import synthesize

    palette = Palette.load()
    lab = np.zeros((32, 32, 3), np.float32)
    lab[..., 0] = 50.0
    lab[:, 16:, 1:] = palette.preset_ab()["red"]
    synthesize(LabMap(lab), n=300, palette=palette, iterations=2)
    loaded = {field.name for field in fields(Palette)} & set(vars(palette))
    assert loaded - {"presets", "extractor"} <= SYNTHESIS_TABLES


@shipped
def test_lazy_palette_arrays_are_the_stored_ones_and_pickle_whole():
    palette = Palette.load()
    with np.load(DEFAULT_PALETTE) as stored:
        assert palette.lut.dtype == np.float32 and np.array_equal(palette.lut, stored["lut"].astype(np.float32))
        assert np.array_equal(palette.exemplar_points, stored["exemplar_points"].astype(np.float64) / 65535.0)
    clone = pickle.loads(pickle.dumps(Palette.load()))
    assert "_pending" not in vars(clone)
    for field in fields(Palette):
        mine, theirs = getattr(palette, field.name), getattr(clone, field.name)
        assert np.array_equal(mine, theirs) if isinstance(mine, np.ndarray) else mine == theirs
    with pytest.raises(AttributeError):
        palette.no_such_table  # noqa: B018


@shipped
def test_lookup_tables_are_mapped_from_a_decompressed_copy_with_the_same_samples(tmp_path):
    """Before the tables are loaded, synthesis samples the stored float16 tables memory-mapped from copies written
    beside the asset on first use: the samples of the loaded float32 tables, bit for bit; a broken copy is not read,
    an earlier asset's copy is removed."""
    asset = tmp_path / "palette.npz"
    asset.write_bytes(DEFAULT_PALETTE.read_bytes())
    earlier = tmp_path / "__pycache__" / "palette.lut.0badc0de.npy"
    earlier.parent.mkdir()
    earlier.write_bytes(b"an earlier asset's table")
    z = np.random.default_rng(5).random((500, 2))
    loaded = Palette.load(asset)
    expected = (_bilinear_reference(loaded.lut, z), _bilinear_reference(loaded.dispersion_lut, z))
    for _ in range(2):  # the first run writes the copies, the second maps them
        palette = Palette.load(asset)
        np.testing.assert_array_equal(palette.pcf_at_latent(z), expected[0])
        np.testing.assert_array_equal(palette.dispersion_at_latent(z), expected[1])
        assert not {"lut", "dispersion_lut"} & set(vars(palette))  # the float32 tables were not loaded
    copies = sorted((tmp_path / "__pycache__").glob("palette.*.npy"))
    assert [copy.name.split(".")[1] for copy in copies] == ["dispersion_lut", "lut"] and earlier not in copies
    copies[1].write_bytes(b"broken")
    np.testing.assert_array_equal(Palette.load(asset).pcf_at_latent(z), expected[0])


def _bilinear_reference(table: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Bilinear samples (k, m) float32 of a (S, S, m) table with nodes at latent (i, j) / (S - 1), one point at a time."""
    size = table.shape[0]
    out = np.empty((len(z), table.shape[2]), np.float32)
    for k, (u, v) in enumerate(np.clip(z, 0.0, 1.0) * (size - 1)):
        i, j = min(int(u), size - 2), min(int(v), size - 2)
        a, b = u - i, v - j
        out[k] = ((1 - a) * (1 - b) * table[i, j].astype(np.float64) + a * (1 - b) * table[i + 1, j]
                  + (1 - a) * b * table[i, j + 1] + a * b * table[i + 1, j + 1])
    return out


@shipped
def test_a_damaged_table_is_a_palette_error_when_it_is_read(tmp_path):
    damaged, short = tmp_path / "damaged.npz", tmp_path / "short.npz"
    with zipfile.ZipFile(DEFAULT_PALETTE) as source, zipfile.ZipFile(damaged, "w") as out, zipfile.ZipFile(short, "w") as cut:
        for name in source.namelist():
            data = source.read(name)
            out.writestr(name, data[: len(data) // 2] if name == "components.npy" else data)  # cut short
            if name != "dispersion_lut.npy":
                cut.writestr(name, data)
    palette = Palette.load(damaged)  # loads: the damaged table is not read yet
    assert palette.lut.shape[:2] == (256, 256)
    with pytest.raises(PatternshopError, match="not a readable palette"):
        palette.components  # noqa: B018
    with pytest.raises(PatternshopError, match="dispersion_lut missing"):
        Palette.load(short)


@shipped
def test_synthesis_imports_neither_scipy_ndimage_nor_scipy_linalg():
    """Both took 0.1-0.3 s of every synthesis's start-up (scipy.linalg through numba's BLAS check,
    :func:`synthesis.kernels.skip_blas_check`); a kernel using BLAS still works afterwards."""
    code = ("import sys\n"
            "import numba\n"
            "import numpy as np\n"
            "import patternshop as ps\n"
            "seen = []\n"
            "def progress(done, total, xy):\n"
            "    seen.append(sorted(m for m in ('scipy.ndimage', 'scipy.linalg') if m in sys.modules))\n"
            f"ps.synthesize({str(ROOT / 'examples' / 'logo.tif')!r}, points=300, iterations=2, progress=progress)\n"
            "dot = numba.njit(lambda a, b: np.dot(a, b))\n"
            "print(seen[0], seen[-1], dot(np.ones(3), np.arange(3.0)))\n")
    assert fresh_python_lines(code)[-1] == "[] [] 3.0"


def test_cached_kernels_load_without_numba_registries_and_give_the_same_points():
    """The synthesis kernels load from numba's cache without its typing and lowering registries (numba.np.arraymath
    and the rest: 0.1 s of start-up; :func:`synthesis.kernels.load_cached_kernels_lazily`): the same points as with
    numba's own loading, on one thread and two, and a kernel compiled afterwards runs."""
    code = ("import hashlib, sys\n"
            "import numba\n"
            "import numpy as np\n"
            "import synthesis.kernels\n"
            "if sys.argv[1] == 'numba':  # numba's own loading, as before\n"
            "    synthesis.kernels.load_cached_kernels_lazily = synthesis.kernels.skip_blas_check\n"
            "import patternshop as ps\n"
            "seen = []\n"
            "def progress(done, total, xy):\n"
            "    seen.append('numba.np.arraymath' in sys.modules)\n"
            "digest = hashlib.sha1()\n"
            "for threads in (1, 2):\n"
            f"    result = ps.synthesize({str(ROOT / 'examples' / 'logo.tif')!r}, points=300, iterations=3, threads=threads,"
            " progress=progress)\n"
            "    digest.update(result.points.xy.tobytes())\n"
            "total = numba.njit(lambda a: np.sort(a)[-1] + a.sum())\n"
            "print(seen[0], digest.hexdigest(), total(np.arange(4.0)))\n")
    runs = {}
    for way in ("lazy", "numba", "lazy"):  # the first run fills numba's cache where it is cold
        result = subprocess.run([sys.executable, "-c", code, way], cwd=ROOT, capture_output=True, text=True, timeout=300,
                                env=os.environ | {"NUMBA_NUM_THREADS": "2"})
        assert result.returncode == 0, result.stderr
        runs[way] = result.stdout.split("\n")[-2].split()
    assert runs["lazy"][0] == "False" and runs["numba"][0] == "True"  # the registries: not loaded / loaded
    assert runs["lazy"][1:] == runs["numba"][1:] and runs["lazy"][2] == "9.0"


def test_garbage_collector_is_off_for_the_start_up_only(monkeypatch):
    """Python's cyclic collector is off while a synthesis starts (numba's import and kernels, the fields: 30-70 ms of
    collections), on again for the iterations and after the call, after a failed start too; left off where the caller
    had it off."""
    import gc

    from synthesis import synthesize as synthesis_module

    seen = []
    build = synthesis_module.MapFields.build
    monkeypatch.setattr(synthesis_module.MapFields, "build",
                        lambda *args, **kwargs: seen.append(("start", gc.isenabled())) or build(*args, **kwargs))
    lab = np.zeros((32, 32, 3), np.float32)
    lab[..., 0] = 50.0
    lab[..., 1:] = Palette.load().preset_ab()["blue"]
    assert gc.isenabled()
    synthesis_module.synthesize(LabMap(lab), n=300, iterations=2,
                                on_iteration=lambda done, xy: seen.append(("iteration", gc.isenabled())))
    assert seen == [("start", False), ("iteration", True), ("iteration", True), ("iteration", True)] and gc.isenabled()
    lab[..., 0] = 100.0  # white: the start fails
    with pytest.raises(PatternshopError, match="white everywhere"):
        synthesis_module.synthesize(LabMap(lab), n=300, iterations=2)
    assert seen[-1] == ("start", False) and gc.isenabled()
    gc.disable()
    try:
        lab[..., 0] = 50.0
        synthesis_module.synthesize(LabMap(lab), n=300, iterations=1)
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_infer_degeneracy_check_leaves_numba_unimported():
    code = ("import sys\n"
            "import export.runtime\n"
            "from synthesis.analysis import check_not_degenerate\n"
            "from synthesis.points import read_points\n"
            f"check_not_degenerate(read_points({str(ROOT / 'examples' / 'logo_points.txt')!r}))\n"
            "print('numba' in sys.modules, 'synthesis.cells' in sys.modules)\n")
    assert fresh_python_lines(code)[-1] == "False False"


def _coincident_by_pairs(xy: np.ndarray, domain: tuple[float, float]) -> int:
    """Plain reference of :func:`coincident_points`: all pairwise distances, occupied cells counted in a set."""
    n, (w, h) = len(xy), domain
    side = float(r_max(n, w * h))
    nx, ny = int(np.ceil(w / side)), int(np.ceil(h / side))
    cells = {(min(max(int(x / side), 0), nx - 1), min(max(int(y / side), 0), ny - 1)) for x, y in xy}
    reach = 0.05 * float(r_max(n, min(len(cells) * side * side, w * h)))
    distance = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(distance, np.inf)
    return int(np.count_nonzero(distance.min(axis=1) < reach))


@pytest.mark.parametrize("case", ["poisson", "small_patch", "pile", "grid", "wide"])
def test_coincident_points_match_all_pairs(case):
    rng = np.random.default_rng(3)
    domain = (1.0, 0.25) if case == "wide" else (1.0, 1.0)
    xy = {"poisson": rng.random((1500, 2)),
          "small_patch": 0.45 + 0.1 * rng.random((1500, 2)),
          "pile": np.concatenate([np.full((700, 2), 0.5), rng.random((800, 2))]),
          "grid": np.round(rng.random((1500, 2)) * 30) / 30,
          "wide": rng.random((1500, 2)) * domain}[case]
    expected = _coincident_by_pairs(xy, domain)
    assert expected > 0  # every case has close pairs: the comparison is not vacuous
    assert coincident_points(PointSet(xy, domain)) == expected


@pytest.mark.parametrize("seed", range(4))
def test_count_within_matches_a_kd_tree(seed):
    """The degeneracy check's exact count (numpy cells) against scipy's k-d tree, its reference: piles, clusters
    straddling the cells, pairs at exactly the reach and just inside it."""
    from scipy.spatial import cKDTree

    from synthesis.analysis import _count_within

    rng = np.random.default_rng(seed)
    reach = 0.01
    parents = rng.random((60, 2))
    xy = np.concatenate([rng.random((3000, 2)),  # Poisson: a few close pairs
                         parents[rng.integers(60, size=2000)] + rng.normal(scale=0.6 * reach, size=(2000, 2)),
                         np.full((300, 2), 0.25),  # a pile
                         [[0.7, 0.7], [0.7 + reach, 0.7], [0.8, 0.8], [0.8 + 0.999 * reach, 0.8],  # at and inside the reach
                          [0.9, 0.1], [0.9 + 0.7 * reach, 0.1 + 0.7 * reach]]])
    nearest = cKDTree(xy).query(xy, k=2)[0][:, 1]
    expected = int(np.count_nonzero(nearest < reach))
    assert 2300 < expected < len(xy)  # neither vacuous nor everything
    fractions = []
    assert _count_within(xy, reach, fractions.append) == expected
    assert fractions[-1] == 1.0 and fractions == sorted(fractions)
