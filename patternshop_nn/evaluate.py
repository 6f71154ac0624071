"""Evaluation of a points-to-map model: out of distribution or on held-out pairs.

``python -m patternshop_nn.evaluate --out eval.json [--quick]`` (the shipped model; ``--model`` for another)

**Suite ``ood``** (default; :mod:`patternshop_nn.ood`): inputs made by other
methods than the synthesiser: stipplings of scikit-image's camera, astronaut,
moon and coins against a KDE at its best bandwidth, stationary Poisson /
Poisson-disk / Lloyd / jitter / Thomas patterns at densities 0.05-1.5 (nearest
preset, lattice locked to 64/32-px phases), empty / one-point / half-empty
inputs, the infer -> synthesize point count from 200 to 50,000 points, and
ONNX Runtime cost. ``--quick`` runs a reduced set (one picture, two densities,
three counts, no synthesis) in about a minute. Writes the JSON, a markdown
table beside it (``--markdown``) and contact sheets (``--previews``).

**Suite ``heldout``**:

1. **Held-out procedural pairs**: made with another seed than the training
   set (``--seed``, default 1000) by ``data_gen.pairs``, into ``--data``.
2. **Stand-ins of each real layout** (faces, animals, churches, treecover;
   :mod:`data_gen.standins`), made into pairs by their own readers.
3. For each set: the model's ``density_mae`` and ``latent_mae``
   (:mod:`patternshop_nn.baselines`) beside the KDE density (best bandwidth)
   and the palette-decoding correlation baseline on the same pairs, the
   relative gains, and the model's a, b error by distance to the nearest
   correlation edge (``model_ab_error_by_edge_distance``: how far a region's
   colour bleeds into its neighbours).
4. **Round trip** on ``--roundtrip`` held-out pairs: points → infer
   → synthesise (same point count) → points, scored against the pair's true
   map: density SSIM (:func:`synthesis.tone.density_fidelity`) and local PCF
   error (mean |edge-aware PCF − target| over points and radii), beside the
   same scores of the original points.

Pairs are cached in ``--data`` (resumable), so a rerun only re-scores.

A Lightning checkpoint (``.ckpt``) is exported to a temporary ONNX model first;
give its training pairs' points per ink with ``--trained-points-per-ink``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from data_gen.shards import Pairs, load_pairs
from export.runtime import OnnxModel
from patternshop_nn.baselines import cached_baselines, density_mae, latent_error_by_edge_distance, latent_mae
from synthesis.errors import PatternshopError, run_module_cli

STANDIN_LAYOUTS = ("faces", "animals", "churches", "treecover")


def predict_pairs(model: OnnxModel, pairs: Pairs, batch_size: int = 8) -> np.ndarray:
    """(K, 3, S, S) model outputs for the pairs' rasters (made at the model's own scale)."""
    outputs = [model.predict(pairs.raster[k : k + batch_size, None].astype(np.float32)) for k in range(0, len(pairs), batch_size)]
    return np.concatenate(outputs)


def score(model: OnnxModel, folder: Path, cells: int = 4) -> dict:
    """Model vs baselines on a pair folder: MAEs and the model's relative gains (positive: the model is better)."""
    pairs = load_pairs(folder)
    targets = pairs.target.transpose(0, 3, 1, 2).astype(np.float32) / 255.0
    predicted = predict_pairs(model, pairs)
    baselines = cached_baselines(folder, pairs, np.arange(len(pairs)), cells)
    model_density, model_latent = density_mae(predicted, targets), latent_mae(predicted, targets)
    return {"pairs": len(pairs), "model_density_mae": round(model_density, 5), "model_latent_mae": round(model_latent, 5),
            **baselines,
            "density_gain_vs_kde": round(1 - model_density / baselines["kde_density_mae"], 4),
            "latent_gain_vs_baseline": round(1 - model_latent / baselines["baseline_latent_mae"], 4),
            "model_ab_error_by_edge_distance": latent_error_by_edge_distance(predicted, targets),
            "per_pair_model_density_mae": [round(density_mae(p, t), 4) for p, t in zip(predicted, targets, strict=True)],
            "per_pair_model_latent_mae": [round(latent_mae(p, t), 4) for p, t in zip(predicted, targets, strict=True)]}


def make_pairs(out_dir: Path, dataset: list[str], items: int, seed: int, workers: int) -> Path:
    """Make (or complete) the pairs of ``dataset`` overrides in ``out_dir`` at the default pair settings; returns ``out_dir``."""
    from data_gen.pairs import generate
    from data_gen.provenance import compose_config

    generate(compose_config("pairs", [*dataset, f"out_dir={out_dir}", f"num_items={items}", f"seed={seed}", f"workers={workers}"]))
    return out_dir


def round_trip(model: OnnxModel, pairs: Pairs, points_per_ink: float, count: int) -> dict:
    """Scores of points → infer → synthesise against the true maps, beside the original points' (see module docstring)."""
    from data_gen.shards import target_to_map
    from export.runtime import points_to_map
    from synthesis.palette import load_palette
    from synthesis.points import PointSet
    from synthesis.synthesize import synthesize
    from synthesis.edgepcf import local_errors
    from synthesis.tone import density_fidelity

    rows = []
    for k in range(min(count, len(pairs))):
        truth = target_to_map(pairs.target[k])
        original = PointSet(pairs.points_of(k).astype(np.float64), truth.domain)
        inferred = points_to_map(original, model, points_per_ink=points_per_ink)
        result = synthesize(inferred, n=len(original), palette=load_palette(), seed=k).points
        row = {}
        for name, points in (("original", original), ("round_trip", result)):
            errors, _ = local_errors(truth, points.xy, len(points))
            row[name] = (float(np.mean(errors)), density_fidelity(points, truth)["ssim"])
        rows.append(row)
    summary = {"pairs": len(rows)}
    for name in ("original", "round_trip"):
        error, ssim = np.array([row[name] for row in rows]).T
        summary[name] = {"local_pcf_error_mean": round(float(error.mean()), 4), "density_ssim_mean": round(float(ssim.mean()), 4)}
    return summary


def evaluate(model_path: str | None, data: Path, items: int, standin_items: int, roundtrip: int, seed: int, workers: int) -> dict:
    from data_gen.standins import write_standin

    model = OnnxModel(model_path, threads=2)
    points_per_ink = model.points_per_ink
    if points_per_ink is None:
        raise PatternshopError(f"{model.path} does not record the points_per_ink it was trained at")
    start = time.perf_counter()
    heldout = make_pairs(data / "procedural", ["dataset=procedural", f"synthesis.points_per_ink={points_per_ink}"],
                         items, seed, workers)
    results = {"model": str(model.path), "metadata": model.metadata, "held_out_seed": seed, "procedural": score(model, heldout)}
    for layout in STANDIN_LAYOUTS if standin_items else ():
        root = data / "standins" / layout
        if not root.exists():
            write_standin(layout, root, standin_items, seed=seed)
        folder = make_pairs(data / f"pairs-{layout}", [f"dataset={layout}", f"dataset.root={root}",
                                                       f"synthesis.points_per_ink={points_per_ink}"], standin_items * 2, seed, workers)
        results[f"standin_{layout}"] = score(model, folder)
    if roundtrip:
        results["round_trip"] = round_trip(model, load_pairs(heldout), points_per_ink, roundtrip)
    results["seconds"] = round(time.perf_counter() - start, 1)
    return results


def onnx_model_path(model: str | None, trained_points_per_ink: float | None, scratch: Path) -> Path:
    """The ONNX file to evaluate: ``model`` itself, the shipped one, or a checkpoint exported into ``scratch``."""
    from export.runtime import DEFAULT_MODEL

    path = Path(model) if model else DEFAULT_MODEL
    if path.suffix != ".ckpt":
        return path
    if trained_points_per_ink is None:
        raise PatternshopError(f"{path}: a checkpoint does not record its training scale; pass --trained-points-per-ink")
    from patternshop_nn.onnx_export import export_onnx

    exported = scratch / f"{path.stem}.onnx"
    export_onnx(path, exported, {"points_per_ink": trained_points_per_ink, "name": path.stem})
    return exported


def run_ood(args: argparse.Namespace, model_path: Path) -> dict:
    from patternshop_nn.ood import evaluate_ood, markdown
    from synthesis.atomic import atomic_write_text
    from synthesis.palette import load_palette

    results = evaluate_ood(model_path, load_palette(args.palette), args.quick, args.seed,
                           Path(args.previews) if args.previews else None, raw=args.raw)
    markdown_path = Path(args.markdown) if args.markdown else Path(args.out).with_suffix(".md")
    atomic_write_text(markdown_path, markdown(results))
    print(markdown(results))
    return results


def main(argv: list[str] | None = None) -> int:
    import tempfile

    parser = argparse.ArgumentParser(prog="python -m patternshop_nn.evaluate", description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--suite", choices=("ood", "heldout"), default="ood", help="which evaluation (default ood)")
    parser.add_argument("--model", help="ONNX model or Lightning checkpoint (default: the shipped model)")
    parser.add_argument("--trained-points-per-ink", type=float, metavar="N", help="a checkpoint's training points per ink")
    parser.add_argument("--out", required=True, help="JSON file for the results")
    parser.add_argument("--quick", action="store_true", help="ood: the reduced set (about a minute)")
    parser.add_argument("--markdown", metavar="MD", help="ood: markdown tables (default: --out with .md)")
    parser.add_argument("--previews", metavar="DIR", help="ood: write contact sheets ood_*.png into DIR")
    parser.add_argument("--raw", action="store_true",
                        help="ood: the network's maps as they come (one run, no ink calibration or smoothing)")
    parser.add_argument("--palette", metavar="NPZ", help="ood: palette whose presets name the colours (default: the shipped one)")
    parser.add_argument("--data", default="data/eval", help="heldout: folder for the held-out pairs and stand-ins (default data/eval)")
    parser.add_argument("--items", type=int, default=48, help="heldout: held-out procedural pairs (default 48)")
    parser.add_argument("--standin-items", type=int, default=6, help="heldout: pictures per stand-in layout (default 6; 0 skips the stand-ins)")
    parser.add_argument("--roundtrip", type=int, default=8, help="heldout: pairs for the round trip (default 8; 0 skips it)")
    parser.add_argument("--seed", type=int, default=1000, help="seed of the evaluation data (default 1000; training uses 0)")
    parser.add_argument("--workers", type=int, default=2, help="heldout: pair-generation processes (default 2)")

    def run(args: argparse.Namespace) -> None:
        from synthesis.atomic import atomic_write_text, check_writable

        check_writable(args.out)  # an unwritable --out stops the run before any work, not after it
        with tempfile.TemporaryDirectory() as scratch:
            model_path = onnx_model_path(args.model, args.trained_points_per_ink, Path(scratch))
            if args.suite == "ood":
                results = run_ood(args, model_path)
            else:
                results = evaluate(str(model_path), Path(args.data), args.items, args.standin_items, args.roundtrip, args.seed,
                                   args.workers)
                print(json.dumps({key: value for key, value in results.items() if key != "metadata"}, indent=2))
        atomic_write_text(Path(args.out), json.dumps(results, indent=2) + "\n")

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
