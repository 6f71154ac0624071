"""Beyond one machine (data_gen.executor): pairs, the palette corpus and convert on a Dask LocalCluster of
2 worker processes give the local pool's results; a worker killed mid-item is retried; a task that kills
its workers every time comes back lost and its item is recorded as skipped; an interrupted run resumes;
train.py trains on 2 CPU processes with Lightning's DDP (gloo).

One cluster (2 processes, 1 thread each, one worker death allowed per task) serves the whole module; the
pairs are the tiny ones of tests/test_pairs.py (32 x 32 maps, 20 synthesis iterations).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli
from test_pairs import folder_of_images, pair_config, same_pairs, save_grey
from upath import UPath

from data_gen import pairs as pairs_module
from data_gen.corpus import CorpusConfig, build_corpus
from data_gen.executor import DASK, SCHEDULER_CONFIG, Executor, Lost
from data_gen.pairs import generate
from data_gen.provenance import compose_config
from data_gen.shards import PARTS, load_pairs, read_manifest
from synthesis.errors import PatternshopError

distributed = pytest.importorskip("distributed")

ITEMS = 8  # 4 shards of 2


@pytest.fixture(scope="module")
def cluster():
    """(scheduler address, client) of a 2-process LocalCluster that allows one worker death per task."""
    import dask

    with dask.config.set(SCHEDULER_CONFIG), distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=logging.ERROR,
            scheduler_kwargs={"allowed_failures": 1}) as local:
        with distributed.Client(local, set_as_default=False) as client:
            yield local.scheduler_address, client


@pytest.fixture(scope="module")
def images(tmp_path_factory) -> Path:
    return folder_of_images(tmp_path_factory.mktemp("images"), ITEMS)


@pytest.fixture(scope="module")
def reference(images, tmp_path_factory):
    """The pairs of the local back end (one worker, in this process)."""
    out = tmp_path_factory.mktemp("reference") / "pairs"
    generate(pair_config(images, out))
    return load_pairs(out)


def on_dask(address: str) -> list[str]:
    return ["executor=dask", f"scheduler={address}"]


def _exit_on_three(task: int) -> int:
    """Kills its worker process on task 3 (every try); other tasks come back doubled."""
    if task == 3:
        os._exit(1)
    return 2 * task


# --- the seam ---------------------------------------------------------------------
def test_executor_settings_are_checked():
    cfg = compose_config("pairs", ["executor=dask", "scheduler=tcp://head:8786", "workers=3"])
    assert Executor.from_config(cfg) == Executor(DASK, 3, "tcp://head:8786")
    assert Executor.from_config(compose_config("palette", [])).describe() == "local x2"
    with pytest.raises(PatternshopError, match="executor must be local or dask"):
        Executor("ray")
    with pytest.raises(PatternshopError, match="needs executor=dask"):
        Executor.from_config(compose_config("pairs", ["scheduler=tcp://head:8786"]))


def test_unreachable_scheduler_is_one_line_error():
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        with pytest.raises(PatternshopError, match="cannot reach the Dask scheduler tcp://127.0.0.1:9"):
            list(Executor(DASK, scheduler="tcp://127.0.0.1:9").map_unordered(abs, [1]))


def test_own_local_cluster_runs_tasks():
    assert sorted(Executor(DASK, workers=2).map_unordered(abs, [-3, 1, -2])) == [1, 2, 3]


def test_task_that_kills_every_worker_comes_back_lost(cluster):
    address, _ = cluster
    outcomes = list(Executor(DASK, scheduler=address).map_unordered(_exit_on_three, list(range(5))))
    lost = [outcome for outcome in outcomes if isinstance(outcome, Lost)]
    assert sorted(outcome for outcome in outcomes if not isinstance(outcome, Lost)) == [0, 2, 4, 8]
    assert len(lost) == 1 and lost[0].task == 3 and "on 2 different workers, but all those workers died" in lost[0].error
    assert "tcp://" in lost[0].error and "Inspecting" not in lost[0].error  # the last worker's address, not Dask's advice


def test_local_pool_stops_when_a_worker_dies():
    with pytest.raises(PatternshopError, match=r"a worker process died \(exit code 1"):
        list(Executor(workers=2).map_unordered(_exit_on_three, list(range(5))))


# --- pairs ------------------------------------------------------------------------
def test_pairs_on_dask_match_the_local_pool(cluster, images, reference, tmp_path):
    out = tmp_path / "pairs"
    summary = generate(pair_config(images, f"file://{out}", *on_dask(cluster[0])))  # an fsspec URL
    assert summary["made_now"] == ITEMS and summary["skipped_now"] == []
    same_pairs(load_pairs(out), reference)
    assert read_manifest(out)["runs"][-1]["executor"] == f"dask {cluster[0]}"


def test_worker_killed_mid_item_is_retried(cluster, images, reference, tmp_path):
    address, client = cluster
    pids = client.run(os.getpid)
    killed: list[int] = []

    def kill_a_busy_worker() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not killed:
            busy = [worker for worker, keys in client.processing().items() if keys and worker in pids]
            if busy:
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(pids[busy[0]])
            time.sleep(0.02)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    out = tmp_path / "pairs"
    try:
        summary = generate(pair_config(images, out, *on_dask(address)))
    finally:
        killer.join()
    assert killed and killed[0] not in client.run(os.getpid).values()
    assert summary["made_now"] == ITEMS and summary["skipped_now"] == []
    same_pairs(load_pairs(out), reference)
    assert not any((out / PARTS).iterdir())  # no part and no temporary of the killed worker left


def test_lost_item_is_recorded_as_skipped(images, reference, tmp_path, monkeypatch):
    """What generate does with a Lost item (here faked: item 5 lost, the rest made in this process)."""
    run_local = Executor.map_unordered

    def lose_five(self, function, tasks, *args, **kwargs):
        yield from run_local(Executor(workers=1), function, [t for t in tasks if t != 5], *args, **kwargs)
        yield Lost(5, "KilledWorker: attempted to run task on 2 different workers, all of which died")

    monkeypatch.setattr(Executor, "map_unordered", lose_five)
    out = tmp_path / "pairs"
    summary = generate(pair_config(images, out, "executor=dask"))
    assert summary["made_now"] == ITEMS - 1 and summary["skipped_now"] == [
        "worker lost: KilledWorker: attempted to run task on 2 different workers, all of which died"]
    skipped = read_manifest(out)["skipped"]
    assert [entry["item"] for entry in skipped] == [5] and skipped[0]["source"].endswith("img05.png")
    pairs = load_pairs(out)
    assert 5 not in pairs.item and np.array_equal(pairs.raster, np.delete(reference.raster, 5, axis=0))


def interrupted_after_first_shard(monkeypatch: pytest.MonkeyPatch, cfg) -> None:  # noqa: ANN001 - a DictConfig
    """Run ``generate(cfg)`` with a Ctrl+C right after its first shard is merged (the folder is then resumable)."""
    merge = pairs_module.merge_chunk

    def interrupt_after_first_shard(*args):
        merge(*args)
        raise KeyboardInterrupt

    monkeypatch.setattr(pairs_module, "merge_chunk", interrupt_after_first_shard)
    with pytest.raises(KeyboardInterrupt):
        generate(cfg)
    monkeypatch.undo()


def test_interrupted_dask_run_resumes(cluster, images, reference, tmp_path, monkeypatch):
    address, client = cluster
    out = tmp_path / "pairs"
    interrupted_after_first_shard(monkeypatch, pair_config(images, out, *on_dask(address)))
    deadline = time.monotonic() + 30
    while any(client.processing().values()) and time.monotonic() < deadline:  # the cluster's work was cancelled
        time.sleep(0.1)
    assert not any(client.processing().values())
    summary = generate(pair_config(images, out, *on_dask(address)))
    assert 0 < summary["made_now"] <= ITEMS - 2 and summary["pairs_in_folder"] == ITEMS
    same_pairs(load_pairs(out), reference)


def test_bad_source_on_dask_is_skipped_with_its_error(cluster, tmp_path):
    root = tmp_path / "images"
    for seed, name in enumerate(["a.png", "b.png", "c.png"]):
        save_grey(root / name, seed)
    (root / "b_garbage.png").write_bytes(b"this is no png" * 10)
    summary = generate(pair_config(root, tmp_path / "pairs", *on_dask(cluster[0])))
    assert summary["made_now"] == 3 and len(summary["skipped_now"]) == 1
    assert "b_garbage.png" in summary["skipped_now"][0] and "unreadable image" in summary["skipped_now"][0]
    assert [entry["item"] for entry in read_manifest(tmp_path / "pairs")["skipped"]] == [2]


def test_pair_folder_at_a_memory_url_resumes_and_trains(images, reference, tmp_path, monkeypatch):
    from patternshop_nn.data import PairDataModule

    url = f"memory://{tmp_path.name}/pairs"
    interrupted_after_first_shard(monkeypatch, pair_config(images, url))
    summary = generate(pair_config(images, url))
    assert summary["made_now"] == ITEMS - 2 and summary["pairs_in_folder"] == ITEMS and summary["out_dir"] == url
    same_pairs(load_pairs(url), reference)
    assert read_manifest(url)["pairs"] == ITEMS and not list(UPath(url, "parts").iterdir())
    data = PairDataModule(url, val_fraction=0.25, baselines=False)
    data.setup()
    assert len(data.train_set) == 6 and len(data.val_set) == 2


# --- palette corpus and convert -----------------------------------------------------
def test_corpus_on_dask_and_in_memory_matches_local(cluster, tmp_path):
    config = CorpusConfig(exemplars=4, points=256, fit_iterations=5, chunk=2)
    local = build_corpus(config, tmp_path / "local", Executor(workers=1))
    remote = build_corpus(config, tmp_path / "dask", Executor(DASK, scheduler=cluster[0]))
    stored = build_corpus(config, f"memory://{tmp_path.name}/cache", Executor(DASK, scheduler=cluster[0]))
    again = build_corpus(config, f"memory://{tmp_path.name}/cache", Executor(DASK, scheduler=cluster[0]))
    assert again["computed_now"] == 0
    for name in ("index", "target", "points", "realised", "fit_rms", "pcf", "features"):
        for other in (remote, stored, again):
            np.testing.assert_array_equal(local[name], other[name], err_msg=name)


def test_convert_on_dask_matches_local(cluster, tmp_path, capsys):
    from export.convert import WRITTEN, convert_points
    from export.runtime import OnnxModel
    from patternshop_nn.networks import DualBranchUNet
    from patternshop_nn.onnx_export import export_onnx
    from synthesis.points import PointSet, write_points

    model = tmp_path / "tiny.onnx"
    export_onnx(DualBranchUNet(base_channels=4, max_channels=8), model, {"name": "tiny"})
    rng = np.random.default_rng(0)
    sources = []
    for name in ("a", "b", "c"):
        sources.append(tmp_path / "points" / f"{name}.txt")
        sources[-1].parent.mkdir(exist_ok=True)
        write_points(PointSet(rng.random((300, 2))), sources[-1])
    local = convert_points(sources, tmp_path / "local", OnnxModel(model), batch_size=2, workers=1)
    remote = convert_points(sources, tmp_path / "dask", OnnxModel(model), batch_size=2, scheduler=cluster[0])
    assert [r.status for r in local] == [r.status for r in remote] == [WRITTEN] * 3
    status, _, err = run_cli(["convert", str(tmp_path / "points"), str(tmp_path / "cli"), "--model", str(model),
                              "--scheduler", cluster[0], "--batch-size", "2", "--no-progress"], capsys)
    assert status == 0 and "wrote 3 of 3 files" in err
    for name in ("a", "b", "c"):
        expected = (tmp_path / "local" / f"{name}.tif").read_bytes()
        assert (tmp_path / "dask" / f"{name}.tif").read_bytes() == expected == (tmp_path / "cli" / f"{name}.tif").read_bytes()
    status, _, err = run_cli(["convert", (tmp_path / "points").as_uri(), (tmp_path / "url").as_uri(), "--model", str(model),
                              "--scheduler", cluster[0], "--batch-size", "2", "--no-progress"], capsys)  # file:// URLs
    assert status == 0 and "wrote 3 of 3 files" in err
    assert all((tmp_path / "url" / f"{n}.tif").read_bytes() == (tmp_path / "local" / f"{n}.tif").read_bytes() for n in "abc")


# --- training on several processes ----------------------------------------------------
def test_train_ddp_on_two_cpu_processes(tmp_path):
    """trainer=ddp_cpu: 2 gloo processes, each training on its half of the 6 training pairs (Lightning's DistributedSampler)."""
    from test_network import ROOT, TINY_MODEL, TINY_PAIRS

    args = [sys.executable, str(ROOT / "train.py"), "trainer=ddp_cpu", f"run_dir={tmp_path / 'run'}",
            f"pairs.out_dir={tmp_path / 'pairs'}", *TINY_PAIRS, *TINY_MODEL, "data.batch_size=1", "data.val_fraction=0.25",
            "data.crop=null", "data.baselines=false", "trainer.enable_progress_bar=false", "trainer.max_epochs=1"]
    done = subprocess.run(args, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["world_size"] == 2 and summary["train_pairs"] == 6
    assert summary["global_step"] == 6  # 3 of the 6 pairs per rank, batch 1, 2 optimiser steps each
    assert (tmp_path / "run" / "checkpoints" / "last.ckpt").is_file()
