"""Export / inference benchmark: the network per 256 x 256 map (ONNX Runtime and torch), their parity, and batch
conversion of point files to maps (``export.convert.convert_points``).

Run with ``make bench`` (or ``python bench/bench_export.py [--quick] [--model FILE]``); results go to
``out/bench/export.json``. Every figure is measured in this run on this machine (CPU count and load average
are recorded: the timings are only as quiet as the machine); targets are printed beside them.

The model is ``--model``, else the shipped ``patternshop_nn/assets/default.onnx``, else an untrained
default-width generator exported to a temporary file (timings do not depend on training; the results say
which). Torch runs the same generator when its weights are at hand (the module exported here, or
``runs/procedural/checkpoints/best.ckpt`` when its weights are the ONNX model's), else an untrained
``DualBranchUNet`` of the ONNX model's width (timing only; parity is then skipped).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper

from common import median_seconds, save_results  # bench/ is on sys.path when run as a script

from patternshop_nn.onnx_export import export_onnx, load_generator
from export.runtime import DEFAULT_MODEL, OnnxModel, map_width, output_to_map, pattern_raster
from patternshop_nn.module import Pix2PixModule
from patternshop_nn.networks import DualBranchUNet
from synthesis.mapio import write_tiff
from synthesis.points import PointSet, read_points, write_points
from synthesis.raster import RASTER_SIZE, point_raster

ROOT = Path(__file__).resolve().parent.parent
CHECKPOINT = ROOT / "runs" / "procedural" / "checkpoints" / "best.ckpt"
LOGO_POINTS = ROOT / "examples" / "logo_points.txt"
TARGET_MS_PER_MAP = 25.0  # ONNX Runtime, 1 thread, one 256 x 256 map
TARGET_FILES_PER_SECOND = 20.0  # convert_points, 2 workers, batch 8, 1 ORT thread, ~20k points per file


# --- the model and its torch twin ---------------------------------------------
def resolve_model(path: str | None, tmp: Path) -> tuple[Path, dict, torch.nn.Module | None]:
    """(ONNX file, description, generator it was exported from when known)."""
    if path is not None:
        if not Path(path).is_file():
            raise SystemExit(f"bench_export: error: {path}: no such model file")
        return Path(path), {"path": str(path), "source": "--model"}, None
    if DEFAULT_MODEL.is_file():
        return DEFAULT_MODEL, {"path": str(DEFAULT_MODEL), "source": "shipped default model"}, None
    torch.manual_seed(0)
    module = Pix2PixModule()
    onnx_path = tmp / "untrained_default_width.onnx"
    export_onnx(module, onnx_path, {"name": "untrained (bench)", "points_per_ink": 8000})
    note = (f"no {DEFAULT_MODEL.relative_to(ROOT)}: an untrained generator of the default width (Pix2PixModule(), "
            "base 12, max 96 channels) exported to a temporary file; timings do not depend on training")
    return onnx_path, {"path": "(temporary) " + onnx_path.name, "source": "untrained", "note": note}, module.generator


def onnx_weights(path: Path) -> dict[str, np.ndarray]:
    """Initialisers by the generator's parameter names (models with ``l_scale`` prefix theirs with ``generator.``)."""
    return {init.name.removeprefix("generator."): numpy_helper.to_array(init) for init in onnx.load(str(path)).graph.initializer}


def same_weights(generator: torch.nn.Module, weights: dict[str, np.ndarray]) -> bool:
    """True when every initializer the exporter kept under its parameter name (those not folded into a convolution)
    equals the generator's, and there are enough of them to tell."""
    state = generator.state_dict()
    shared = [name for name in weights if name in state]
    return len(shared) >= 10 and all(np.array_equal(weights[name], state[name].numpy()) for name in shared)


def width_of(weights: dict[str, np.ndarray], levels: int) -> tuple[int, int]:
    """(base_channels, max_channels) of the exported generator: its first convolution and its deepest level."""
    base = int(weights["first.weight"].shape[0])
    deepest = [w.shape[0] for name, w in weights.items() if name.startswith("downs.") and w.ndim == 4]
    return base, int(max(deepest, default=min(base * 2 ** (levels - 1), 96)))


def torch_generator(model: OnnxModel, exported_from: torch.nn.Module | None) -> tuple[torch.nn.Module, dict]:
    """The torch generator to time and compare, and what it is."""
    if exported_from is not None:
        return exported_from.eval(), {"source": "the module exported here", "same_weights_as_onnx": True}
    weights = onnx_weights(model.path)
    if CHECKPOINT.is_file():
        generator = load_generator(CHECKPOINT).eval()
        same = same_weights(generator, weights)
        info = {"source": str(CHECKPOINT.relative_to(ROOT)), "same_weights_as_onnx": same}
        if same:
            return generator, info
        info["note"] = "the checkpoint's weights differ from the ONNX model's"
    else:
        info = {"source": None, "note": f"no {CHECKPOINT.relative_to(ROOT)}"}
    levels = int((model.metadata.get("generator") or {}).get("levels") or 6)
    upsample = (model.metadata.get("generator") or {}).get("upsample") or "transposed"
    base, widest = width_of(weights, levels)
    if upsample == "nearest":  # the exported function rebuilt exactly (patternshop_nn.onnx_import)
        from patternshop_nn.onnx_import import generator_from_onnx

        generator = generator_from_onnx(model.path, levels, base, widest, l_scale="scale.1.weight" in weights)
        info.update({"source": f"{model.path.name} rebuilt by patternshop_nn.onnx_import.generator_from_onnx",
                     "same_weights_as_onnx": True})
        info.pop("note", None)
        return generator.eval(), info
    torch.manual_seed(0)
    generator = DualBranchUNet(1, levels, base, widest, upsample=upsample).eval()
    parameters = sum(p.numel() for p in generator.parameters())
    expected = (model.metadata.get("generator") or {}).get("parameters")
    info.update({"source": f"untrained DualBranchUNet(levels={levels}, base_channels={base}, max_channels={widest}, "
                           f"upsample={upsample!r})",
                 "same_weights_as_onnx": False, "parameters": parameters, "onnx_parameters": expected,
                 "note": info["note"] + ": an untrained generator of the same width, for timing only"})
    return generator, info


# --- per-map timings ------------------------------------------------------------
def per_map(model_path: Path, generator: torch.nn.Module, repeats: int) -> dict:
    rng = np.random.default_rng(0)
    rasters = {batch: rng.random((batch, 1, RASTER_SIZE, RASTER_SIZE), dtype=np.float32) for batch in (1, 8)}
    out: dict = {"raster_px": RASTER_SIZE, "onnxruntime": {}, "torch": {}}
    for threads in (1, 2):
        model = OnnxModel(model_path, threads=threads)
        row = {}
        for batch, x in rasters.items():
            seconds, _ = median_seconds(lambda x=x: model.predict(x), repeats=repeats, warmup=1)
            row[f"batch_{batch}_ms_per_map"] = round(1000 * seconds / batch, 2)
        out["onnxruntime"][f"threads_{threads}"] = row
    caller = torch.get_num_threads()
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            row = {}
            for batch, x in rasters.items():
                tensor = torch.from_numpy(x)

                def forward(tensor: torch.Tensor = tensor) -> None:
                    with torch.no_grad():
                        generator(tensor)

                seconds, _ = median_seconds(forward, repeats=repeats, warmup=1)
                row[f"batch_{batch}_ms_per_map"] = round(1000 * seconds / batch, 2)
            out["torch"][f"threads_{threads}"] = row
    finally:
        torch.set_num_threads(caller)
    ort = out["onnxruntime"]["threads_1"]["batch_1_ms_per_map"]
    out["target"] = f"ONNX Runtime, 1 thread, batch 1: <= {TARGET_MS_PER_MAP:g} ms per 256x256 map"
    out["target_met"] = ort <= TARGET_MS_PER_MAP
    out["repeats"] = repeats
    return out


def fusion(generator: torch.nn.Module, tmp: Path, repeats: int) -> dict:
    """ONNX Runtime ms per 256 x 256 map (1 thread, batch 1) of the torch twin exported with and without fused
    nearest up-sampling (:func:`patternshop_nn.networks.fuse_upsampling`), and their largest difference."""
    raster = np.random.default_rng(2).random((1, 1, RASTER_SIZE, RASTER_SIZE), dtype=np.float32)
    out: dict = {}
    for fused in (False, True):
        path = tmp / f"twin_{'fused' if fused else 'unfused'}.onnx"
        export_onnx(generator, path, {"name": "bench twin", "points_per_ink": 8000}, fuse=fused)
        model = OnnxModel(path, threads=1)
        seconds, _ = median_seconds(lambda model=model: model.predict(raster), repeats=repeats, warmup=1)
        out[f"{'fused' if fused else 'unfused'}_ms_per_map"] = round(1000 * seconds, 2)
        out[f"{'fused' if fused else 'unfused'}_output"] = model.predict(raster)
    out["max_abs_difference"] = float(np.abs(out.pop("fused_output") - out.pop("unfused_output")).max())
    out["speed_up"] = round(out["unfused_ms_per_map"] / out["fused_ms_per_map"], 2)
    return out


def parity(model: OnnxModel, generator: torch.nn.Module, info: dict) -> dict:
    if not info["same_weights_as_onnx"]:
        return {"skipped": "the torch generator is not the ONNX model's (" + info.get("note", "") + ")"}

    def difference(rasters: np.ndarray) -> float:
        with torch.no_grad():
            expected = generator(torch.from_numpy(rasters)).numpy()
        return float(np.abs(model.predict(rasters) - expected).max())

    random = np.random.default_rng(1).random((2, 1, RASTER_SIZE, RASTER_SIZE), dtype=np.float32)
    points = read_points(LOGO_POINTS)
    at_scale, _ = pattern_raster(points, model.raster_size, model.points_per_ink, 20_000)
    return {"random_rasters_256": difference(random),
            "logo_points_raster_256": difference(point_raster(points.xy)[None, None]),
            f"logo_points_raster_{at_scale.shape[0]}_at_20000_points_per_ink": difference(at_scale[None, None]),
            "tolerance": 1e-4}


# --- batch conversion ------------------------------------------------------------
def make_point_files(folder: Path, count: int, seed: int = 0) -> tuple[list[Path], list[int]]:
    """``count`` unit-square point files of 18,000-20,000 points: uniform random (even files) or jittered grid
    (odd files), thinned by a linear density ramp of random direction and contrast."""
    rng = np.random.default_rng(seed)
    paths, counts = [], []
    for i in range(count):
        n = int(rng.integers(18_000, 20_001))
        if i % 2 == 0:
            candidates = rng.random((int(2.5 * n), 2))
        else:
            side = math.ceil(math.sqrt(2.5 * n))
            cells = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)
            candidates = (cells + rng.random(cells.shape)) / side
        angle, contrast = rng.uniform(0, 2 * math.pi), rng.uniform(0.0, 0.8)
        direction = np.array([math.cos(angle), math.sin(angle)])
        t = candidates @ direction
        t = (t - t.min()) / max(t.max() - t.min(), 1e-9)
        kept = candidates[rng.random(len(candidates)) < 1.0 - contrast * t]
        xy = kept[rng.choice(len(kept), size=min(n, len(kept)), replace=False)]
        path = folder / f"pattern_{i:03d}.txt"
        write_points(PointSet(xy, (1.0, 1.0)), path)
        paths.append(path)
        counts.append(len(xy))
    return paths, counts


def _seconds(function: Callable[[], object]) -> float:
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def stages(paths: list[Path], model: OnnxModel, points_per_ink: float, out_dir: Path, samples: int) -> dict:
    """Median per-file milliseconds of each step of a conversion, in this process, one thread."""
    points = [read_points(p) for p in paths[:samples]]
    read = [_seconds(lambda p=p: read_points(p)) for p in paths[:samples]]
    raster = [_seconds(lambda s=s: pattern_raster(s, model.raster_size, model.points_per_ink, points_per_ink)) for s in points]
    rasters = [pattern_raster(s, model.raster_size, model.points_per_ink, points_per_ink) for s in points]
    batch = np.stack([rasters[k % len(rasters)][0] for k in range(8)])[:, None]
    network, _ = median_seconds(lambda: model.predict(batch), repeats=2, warmup=1)
    output = model.predict(batch[:1])[0]
    scale, domain = rasters[0][1], points[0].domain

    def write() -> None:
        write_tiff(output_to_map(output, domain, scale, map_width(domain, model, None)), out_dir / "stage.tif", 16)

    written, _ = median_seconds(write, repeats=3, warmup=1)
    ms = {"read_points": 1000 * float(np.median(read)), "rasterise": 1000 * float(np.median(raster)),
          "network_batch_8": 1000 * network / 8, "decode_and_write_tiff": 1000 * written}
    ms = {k: round(v, 1) for k, v in ms.items()}
    ms["total_cpu"] = round(sum(ms.values()), 1)
    return ms


CONVERT_CODE = """
import json, sys, time
from export.convert import WRITTEN, convert_points, point_files
from export.runtime import OnnxModel
model_path, in_dir, out_dir, points_per_ink, limit = sys.argv[1:]
paths = point_files(in_dir)[: int(limit)]
model = OnnxModel(model_path, threads=1)
start = time.perf_counter()
results = convert_points(paths, out_dir, model, batch_size=8, workers=2, overwrite=True, points_per_ink=float(points_per_ink))
seconds = time.perf_counter() - start
print(json.dumps({"files": len(paths), "seconds": seconds, "written": sum(r.status == WRITTEN for r in results),
                  "files_with_warnings": sum(bool(r.warnings) for r in results)}))
"""


def convert_in_subprocess(model_path: Path, in_dir: Path, out_dir: Path, points_per_ink: float, limit: int) -> dict:
    """Time ``convert_points`` in a fresh process whose spawned workers import only what conversion needs
    (a worker re-imports its parent's main module: this script would drag torch and lightning into each)."""
    command = [sys.executable, "-c", CONVERT_CODE, *map(str, (model_path, in_dir, out_dir, points_per_ink, limit))]
    output = subprocess.run(command, capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(output.stdout.strip().splitlines()[-1])


def conversion(paths: list[Path], counts: list[int], model_path: Path, points_per_ink: float, tmp: Path,
               samples: int) -> dict:
    model = OnnxModel(model_path, threads=1)
    side = pattern_raster(read_points(paths[0]), model.raster_size, model.points_per_ink, points_per_ink)[0].shape[0]
    out_dir = tmp / f"maps_{int(points_per_ink)}"
    run = convert_in_subprocess(model_path, paths[0].parent, out_dir, points_per_ink, len(paths))
    start_up = convert_in_subprocess(model_path, paths[0].parent, tmp / "start_up", points_per_ink, 2)
    files_per_second = run["files"] / run["seconds"]
    scale = model.raster_size * math.sqrt(points_per_ink / (model.points_per_ink or points_per_ink))
    return {"points_per_ink": points_per_ink, "pixels_per_unit": round(scale, 1), "raster_px": side,
            "mean_ink": round(float(np.mean(counts)) / points_per_ink, 3),
            "files": run["files"], "written": run["written"], "files_with_warnings": run["files_with_warnings"],
            "seconds": round(run["seconds"], 2), "files_per_second": round(files_per_second, 2),
            "target_met": files_per_second >= TARGET_FILES_PER_SECOND,
            "two_files_seconds": round(start_up["seconds"], 2),
            "stages_ms_per_file_one_process": stages(paths, model, points_per_ink, tmp, samples)}


# --- main ----------------------------------------------------------------------------
def report_lines(results: dict) -> list[str]:
    lines = [f"model: {results['model']['path']} ({results['model']['source']})",
             f"torch twin: {results['torch_generator']['source']}"]
    per = results["per_map_256"]
    for engine in ("onnxruntime", "torch"):
        for threads, row in per[engine].items():
            lines.append(f"{engine:12s} {threads}: batch 1 {row['batch_1_ms_per_map']:7.2f} ms/map, "
                         f"batch 8 {row['batch_8_ms_per_map']:7.2f} ms/map")
    lines.append(f"target {per['target']}: {'met' if per['target_met'] else 'NOT met'}")
    fused = results["fusion"]
    lines.append(f"torch twin exported unfused {fused['unfused_ms_per_map']:.2f} ms/map, fused {fused['fused_ms_per_map']:.2f} ms/map "
                 f"(x{fused['speed_up']:.2f}, max difference {fused['max_abs_difference']:.2g})")
    parity_result = results["parity"]
    if "skipped" in parity_result:
        lines.append(f"parity: skipped ({parity_result['skipped']})")
    else:
        values = ", ".join(f"{k} {v:.2g}" for k, v in parity_result.items() if k != "tolerance")
        lines.append(f"parity max |torch - ORT|: {values}")
    for run in results["conversion"]["runs"]:
        lines.append(f"convert {run['files']} files at {run['points_per_ink']:g} points per ink ({run['raster_px']} px rasters): "
                     f"{run['seconds']:.1f} s, {run['files_per_second']:.1f} files/s (2 files: {run['two_files_seconds']:.1f} s) "
                     f"(target >= {TARGET_FILES_PER_SECOND:g}: {'met' if run['target_met'] else 'NOT met'}); "
                     f"per file in one process {run['stages_ms_per_file_one_process']}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run: fewer repeats, 20 files")
    parser.add_argument("--model", metavar="FILE", help="ONNX model (default: the shipped default model, else an untrained one)")
    args = parser.parse_args()
    started = time.perf_counter()
    results: dict = {"quick": args.quick,
                     "machine": {"cpus": os.cpu_count(), "load_average_1min_start": round(os.getloadavg()[0], 2)}}
    with tempfile.TemporaryDirectory(prefix="bench_export_") as folder:
        tmp = Path(folder)
        model_path, results["model"], exported_from = resolve_model(args.model, tmp)
        model = OnnxModel(model_path, threads=1)
        results["model"]["trained_points_per_ink"] = model.points_per_ink
        generator, results["torch_generator"] = torch_generator(model, exported_from)
        results["per_map_256"] = per_map(model_path, generator, repeats=3 if args.quick else 15)
        results["fusion"] = fusion(generator, tmp, repeats=3 if args.quick else 15)
        results["parity"] = parity(model, generator, results["torch_generator"])

        count = 20 if args.quick else 200
        files_dir = tmp / "points"
        files_dir.mkdir()
        clock = time.perf_counter()
        paths, counts = make_point_files(files_dir, count)
        make_files_seconds = time.perf_counter() - clock
        runs = [conversion(paths, counts, model_path, ppi, tmp, samples=4 if args.quick else 8) for ppi in (50_000, 20_000)]
        results["conversion"] = {
            "setup": f"{count} unit-square .txt files of {min(counts)}-{max(counts)} points (uniform random and jittered "
                     "grid, thinned by a random linear density ramp); convert_points in a fresh process with 2 worker processes "
                     "(spawned, their start-up included: two_files_seconds is a run on 2 files), batch 8, 1 ONNX Runtime "
                     "thread, 16-bit TIFFs; one timed run each",
            "make_files_seconds": round(make_files_seconds, 1),
            "target": f">= {TARGET_FILES_PER_SECOND:g} files/s on 2 cores",
            "runs": runs,
        }
    results["machine"]["load_average_1min_end"] = round(os.getloadavg()[0], 2)
    results["bench_seconds"] = round(time.perf_counter() - started, 1)
    for line in report_lines(results):
        print(line, flush=True)
    save_results("export", results)


if __name__ == "__main__":
    main()
