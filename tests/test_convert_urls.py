"""``convert`` between fsspec URLs (export.convert through data_gen.storage, issue 29): a ``memory://`` folder gives
the local run's bytes, a rerun resumes, a bad file fails alone and is named by its URL, an output interrupted
mid-write leaves nothing behind; ``file://`` URLs with two worker processes; ``ps.convert`` is what the CLI runs.

``memory://`` lives in one process: convert runs it in the calling process (tests here ask for 2 workers to check
that); the multi-process cases use ``file://``. tests/test_distributed.py runs URLs on a Dask cluster.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli
from upath import UPath

import patternshop as ps
from export.convert import FAILED, SKIPPED, WRITTEN
from patternshop_nn.networks import DualBranchUNet
from patternshop_nn.onnx_export import export_onnx
from synthesis.labmap import LabMap
from synthesis.mapio import write_channels, write_tiff
from synthesis.points import PointSet, read_points, write_points

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def tiny_onnx(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("model") / "tiny.onnx"
    export_onnx(DualBranchUNet(base_channels=4, max_channels=8), path, {"name": "tiny"})
    return path


def point_folder(folder: Path) -> Path:
    """Two good point files (one .npy) and a bad one."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    write_points(PointSet(rng.random((300, 2))), folder / "a.txt")
    np.save(folder / "b.npy", rng.random((200, 2)))
    (folder / "bad.txt").write_text("0.1 0.2\n0.3 zz\n")
    return folder


def upload(folder: Path, url: str) -> str:
    """Copy a local folder's files to ``url``; returns ``url``."""
    for path in folder.iterdir():
        (UPath(url) / path.name).write_bytes(path.read_bytes())
    return url


def test_memory_folder_converts_like_a_local_folder_and_resumes(tiny_onnx, tmp_path):
    local = point_folder(tmp_path / "points")
    url, out = upload(local, f"memory://{tmp_path.name}/points"), f"memory://{tmp_path.name}/maps"
    expected = ps.convert(local, tmp_path / "maps", model=tiny_onnx, workers=1)
    results = ps.convert(url, out, model=tiny_onnx, workers=2)  # memory:// is per process: run here
    assert [r.status for r in expected] == [r.status for r in results] == [WRITTEN, WRITTEN, FAILED]
    assert results[2].error == f"{url}/bad.txt:2: 'zz' is not a number"
    assert str(results[0].source) == f"{url}/a.txt" and str(results[0].output) == f"{out}/a.tif"
    for name in ("a", "b"):
        assert UPath(f"{out}/{name}.tif").read_bytes() == (tmp_path / "maps" / f"{name}.tif").read_bytes()
    assert sorted(p.name for p in UPath(out).iterdir()) == ["a.tif", "b.tif"]

    again = ps.convert(url, out, model=tiny_onnx, workers=1)  # outputs exist: resumed
    assert [r.status for r in again] == [SKIPPED, SKIPPED, FAILED]
    assert [r.status for r in ps.convert(url, out, model=tiny_onnx, workers=1, overwrite=True)] == [WRITTEN, WRITTEN, FAILED]


def test_output_interrupted_mid_write_leaves_no_object(tiny_onnx, tmp_path, monkeypatch):
    import synthesis.mapio

    def half_then_fail(lab_map, path, bits=16):
        Path(path).write_bytes(b"II*\0half")
        raise OSError("disk gone")

    url = upload(point_folder(tmp_path / "points"), f"memory://{tmp_path.name}/points")
    monkeypatch.setattr(synthesis.mapio, "write_tiff", half_then_fail)
    results = ps.convert(url, f"memory://{tmp_path.name}/maps", model=tiny_onnx, workers=1)
    assert [r.status for r in results] == [FAILED] * 3 and results[0].error == "disk gone"
    assert list(UPath(f"memory://{tmp_path.name}/maps").iterdir()) == []


def test_cli_between_file_urls_with_two_workers(tiny_onnx, tmp_path, capsys):
    local = point_folder(tmp_path / "points")
    ps.convert(local, tmp_path / "expected", model=tiny_onnx, workers=1)
    argv = ["convert", (tmp_path / "points").as_uri(), (tmp_path / "maps").as_uri(), "--model", str(tiny_onnx),
            "--workers", "2", "--batch-size", "1", "--no-progress"]
    status, _, err = run_cli(argv, capsys)
    assert status == 1 and "wrote 2 of 3 files" in err and f"{local / 'bad.txt'}:2: 'zz' is not a number" in err
    for name in ("a", "b"):
        assert (tmp_path / "maps" / f"{name}.tif").read_bytes() == (tmp_path / "expected" / f"{name}.tif").read_bytes()
    status, _, err = run_cli(argv, capsys)
    assert status == 1 and "wrote 0 of 3 files" in err and "skipped 2" in err


def test_resynthesize_memory_maps_like_local_ones(tmp_path):
    folder = tmp_path / "maps"
    folder.mkdir()
    lab = np.empty((8, 16, 3), np.float32)
    lab[...] = (70.0, 10.0, -20.0)
    write_tiff(LabMap(lab[:, :8]), folder / "square.tif")
    write_channels(LabMap(lab), folder / "wide.L.png")
    (folder / "broken.tif").write_bytes(b"junk")
    url, out = upload(folder, f"memory://{tmp_path.name}/maps"), f"memory://{tmp_path.name}/points"
    options = dict(resynthesize=True, points=40, iterations=3, workers=1)
    expected = ps.convert(folder, tmp_path / "points", **options)
    results = ps.convert(url, out, **options)
    assert [r.status for r in expected] == [r.status for r in results] == [FAILED, WRITTEN, WRITTEN]
    assert results[0].error.startswith(f"{url}/broken.tif: not a readable TIFF")
    for name in ("square", "wide"):
        assert UPath(f"{out}/{name}.txt").read_bytes() == (tmp_path / "points" / f"{name}.txt").read_bytes()
    assert read_points(tmp_path / "points" / "wide.txt").domain == (1.0, 0.5)


def test_memory_folders_on_an_in_process_dask_cluster(tiny_onnx, tmp_path):
    distributed = pytest.importorskip("distributed")
    import logging

    local = point_folder(tmp_path / "points")
    url, out = upload(local, f"memory://{tmp_path.name}/points"), f"memory://{tmp_path.name}/maps"
    expected = ps.convert(local, tmp_path / "maps", model=tiny_onnx, workers=1)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None,
                                  silence_logs=logging.ERROR) as cluster:
        results = ps.convert(url, out, model=tiny_onnx, scheduler=cluster.scheduler_address, batch_size=1)
    assert [r.status for r in results] == [r.status for r in expected]
    assert results[2].error == f"{url}/bad.txt:2: 'zz' is not a number"
    for name in ("a", "b"):
        assert UPath(f"{out}/{name}.tif").read_bytes() == (tmp_path / "maps" / f"{name}.tif").read_bytes()


def test_convert_api_errors(tmp_path):
    with pytest.raises(ps.PatternshopError, match="no such folder"):
        ps.convert(f"memory://{tmp_path.name}/missing", tmp_path / "out")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ps.PatternshopError, match="no point files"):
        ps.convert(tmp_path / "empty", tmp_path / "out")
    with pytest.raises(ps.PatternshopError, match="does not apply"):
        ps.convert(tmp_path / "empty", tmp_path / "out", resynthesize=True, model="x.onnx")
    with pytest.raises(ps.PatternshopError, match="workers"):
        ps.convert(tmp_path / "empty", tmp_path / "out", workers=0)


def test_local_paths_leave_universal_pathlib_unimported():
    """A local run does not import universal_pathlib (fsspec's 40 ms at start-up); text it may read as a URL still
    goes through it, and gives what it gave before (file: URLs local, memory: ones not)."""
    code = ("import sys\n"
            "from data_gen.storage import as_path, in_process, is_local\n"
            "local = [as_path(text) for text in ('a/b', './c', 'C:/d', 'memory:e', 's3:f/g', '')]\n"
            "print(all(is_local(p) and not in_process(p) for p in local), [str(p) for p in local], 'upath' in sys.modules)\n"
            "print(as_path('file:///tmp/x'), is_local(as_path('memory:/y')), in_process(as_path('memory://y')), 'upath' in sys.modules)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert result.stdout.splitlines() == ["True ['a/b', 'c', 'C:/d', 'memory:e', 's3:f/g', '.'] False", "/tmp/x False True True"]
