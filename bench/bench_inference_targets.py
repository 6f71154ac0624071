"""Issue 28's development targets for a model, read through ``infer``'s own path (one thread, default ``InferConfig``).

1. **Textured development pictures** (docs/evaluation.md): ``coins``, ``astronaut`` and the first ten items of
   ``dataset=textures`` (map size 256, seed 0), each stippled with 20,000 points by the development stipplers
   (random, Lloyd, Floyd-Steinberg): the model's SSIM of L against the oracle KDE's (target: ≥, per case).
2. **Stationary processes not in the training set** (``bench_rotation.py``'s generators: scrambled Sobol, Matérn II
   hard-core, square and hexagonal lattices with 5 % jitter, Thomas clusters), 20,000 points on the unit square
   (read as ``infer`` reads a file without a header), 2 realisations × 4 random rotations with random shifts: the
   map's mean a, b against ``analyze``'s colour of the same points (``Palette.decode``; target ≤ 10 ab), and the
   spread of the map's colour over the rotations of one realisation (target ≤ 8).
3. **Poisson stipplings decode white**: ``camera`` and ``coins`` stippled by density-proportional Poisson points
   (20,000): the chroma sqrt(a² + b²) of the map where the picture is light (density < 0.15) and within 2 map px of
   a density edge (the picture's gradient above its 95th percentile); target: 95th percentile ≤ 15.
4. **Inventing nothing**: ``patternshop_nn.ood.inventions`` (empty and one-point inputs) and the share of the
   network's variance locked to a 64-px phase on a uniform pattern (``ood.lattice``).

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_inference_targets.py [--model M] [--quick] [--out out/bench/inference_targets.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import binary_dilation, sobel

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_rotation import PROCESSES, spread  # noqa: E402

from data_gen.makers import build_maker  # noqa: E402
from data_gen.provenance import compose_config  # noqa: E402
from data_gen.stipplers import METHODS  # noqa: E402
from export.evidence import ScaleChoice  # noqa: E402
from export.runtime import OnnxModel, infer_map  # noqa: E402
from patternshop_nn import ood  # noqa: E402
from synthesis.palette import load_palette  # noqa: E402
from synthesis.points import PointSet  # noqa: E402

POINTS = 20_000
SEED = 0
TEXTURE_ITEMS = 10
LIGHT_DENSITY = 0.15
EDGE_QUANTILE = 0.95
EDGE_REACH_PX = 2
WHITE_CHROMA = 15.0
COLOUR_TARGET, SPREAD_TARGET = 10.0, 8.0


def textured_pictures(count: int) -> list[tuple[str, np.ndarray, tuple[float, float]]]:
    """(name, density (H, W) in [0, 1], domain) of coins, astronaut and the first ``count`` textures items."""
    pictures = [(name, *ood.picture_density(name)) for name in ("coins", "astronaut")]
    maker = build_maker(compose_config("pairs", ["dataset=textures"]).dataset, 256)
    for item in range(count):
        lab_map = maker.make(item, np.random.default_rng([SEED, item]))
        pictures.append((f"textures {item}", np.clip(1.0 - lab_map.L / 100.0, 0.0, 1.0), (1.0, 1.0)))
    return pictures


def read(xy: np.ndarray, domain: tuple[float, float], density: np.ndarray | None, model: OnnxModel):
    """``infer``'s map of points: at their true scale when the picture is known, else as a file without a header."""
    scale = ScaleChoice(ood.points_per_ink_of(len(xy), density), False) if density is not None else None
    return infer_map(PointSet(xy, domain), model, scale=scale).lab_map


def textured(model: OnnxModel, count: int) -> list[dict]:
    """Section 1 of the module docstring."""
    rows = []
    for name, density, domain in textured_pictures(count):
        for method in ood.STIPPLERS:
            xy = METHODS[method](density, POINTS, domain, np.random.default_rng(SEED))
            lab_map = read(xy, domain, density, model)
            truth_L = 100.0 * (1.0 - ood.resample(density, lab_map.L.shape))
            ssim, mae = ood.l_scores(truth_L, lab_map.L.astype(np.float64))
            oracle = ood.kde_scores(xy, truth_L, ood.points_per_ink_of(len(xy), density))
            rows.append({"picture": name, "method": method, "ssim": round(ssim, 4), "mae": round(mae, 3),
                         "oracle_ssim": oracle["kde_ssim"], "oracle_mae": oracle["kde_mae"],
                         "ssim_at_least_oracle": bool(round(ssim, 4) >= oracle["kde_ssim"])})
            print(f"  {name:12s} {method:16s} SSIM {ssim:.3f} (oracle {oracle['kde_ssim']:.3f})", flush=True)
    return rows


def stationary(model: OnnxModel, seeds: int, angles: int) -> dict:
    """Section 2 of the module docstring."""
    palette = load_palette()
    result = {}
    for index, (name, realise) in enumerate(PROCESSES.items()):
        rng = np.random.default_rng([index, 28])
        network, analysed, spreads = [], [], []
        for _ in range(seeds):
            turn = realise(POINTS, rng)
            views = [turn(angle, rng.random(2)) for angle in rng.uniform(0.0, np.pi / 2, angles)]
            colours = np.array([read(xy, (1.0, 1.0), None, model).ab.reshape(-1, 2).mean(axis=0) for xy in views])
            network.append(colours)
            analysed.append([palette.decode(xy) for xy in views])
            spreads.append(spread(colours))
        network_mean, analysed_mean = np.concatenate(network).mean(axis=0), np.array(analysed).reshape(-1, 2).mean(axis=0)
        distance = float(np.linalg.norm(network_mean - analysed_mean))
        result[name] = {"network_ab": np.round(network_mean.astype(float), 1).tolist(), "analyze_ab": np.round(analysed_mean, 1).tolist(),
                        "distance": round(distance, 1), "rotation_spread": round(max(spreads), 1),
                        "colour_met": distance <= COLOUR_TARGET, "spread_met": max(spreads) <= SPREAD_TARGET}
        print(f"  {name:18s} network {result[name]['network_ab']} analyze {result[name]['analyze_ab']} "
              f"distance {distance:.1f} spread {max(spreads):.1f}", flush=True)
    return result


def poisson_white(model: OnnxModel) -> list[dict]:
    """Section 3 of the module docstring."""
    rows = []
    for name in ("camera", "coins"):
        density, domain = ood.picture_density(name)
        xy = METHODS["random"](density, POINTS, domain, np.random.default_rng(SEED))
        lab_map = read(xy, domain, density, model)
        truth = ood.resample(density, lab_map.L.shape)
        chroma = np.linalg.norm(lab_map.ab, axis=-1)
        gradient = np.hypot(sobel(truth, 0), sobel(truth, 1))
        edges = binary_dilation(gradient > np.quantile(gradient, EDGE_QUANTILE), iterations=EDGE_REACH_PX)
        row = {"picture": name}
        for region, mask in (("light", truth < LIGHT_DENSITY), ("edges", edges)):
            row[f"{region}_pixels"] = int(mask.sum())
            row[f"{region}_chroma_mean"] = round(float(chroma[mask].mean()), 1) if mask.any() else None
            row[f"{region}_chroma_p95"] = round(float(np.quantile(chroma[mask], 0.95)), 1) if mask.any() else None
        row["met"] = all(row[f"{r}_chroma_p95"] is None or row[f"{r}_chroma_p95"] <= WHITE_CHROMA for r in ("light", "edges"))
        print(f"  {name}: chroma p95 light {row['light_chroma_p95']} edges {row['edges_chroma_p95']}", flush=True)
        rows.append(row)
    return rows


def nothing_invented(model: OnnxModel) -> dict:
    """Section 4 of the module docstring."""
    result = ood.inventions(model, load_palette(), SEED, synthesise=False, raw=False, previews=[])
    uniform = infer_map(PointSet(METHODS["random"](np.full((256, 256), 0.5), POINTS, (1.0, 1.0), np.random.default_rng(SEED))), model)
    result.update(ood.lattice(uniform))
    result["met"] = bool(result["empty_min_L"] >= 97 and result["one_point_share_L95"] >= 0.99
                         and max(v for k, v in result.items() if k.startswith(("L_locked_64", "ab_locked_64"))) <= 0.05)
    return result


def targets(results: dict) -> list[dict]:
    """(figure, target, measured, met) rows of the issue's development targets."""
    cases = results["textured"]
    rows = [{"figure": "textured pictures: cases with SSIM >= the oracle KDE's", "target": f"{len(cases)} of {len(cases)}",
             "measured": f"{sum(c['ssim_at_least_oracle'] for c in cases)} of {len(cases)}",
             "met": all(c["ssim_at_least_oracle"] for c in cases)}]
    for name, row in results["stationary"].items():
        rows.append({"figure": f"{name}: network colour from analyze's / spread over rotations", "target": "<= 10 / <= 8",
                     "measured": f"{row['distance']} / {row['rotation_spread']}", "met": row["colour_met"] and row["spread_met"]})
    for row in results["poisson_white"]:
        rows.append({"figure": f"Poisson {row['picture']}: chroma p95 in light areas / along edges", "target": "<= 15",
                     "measured": f"{row['light_chroma_p95']} / {row['edges_chroma_p95']}", "met": row["met"]})
    invented = results["nothing_invented"]
    rows.append({"figure": "empty min L / one point: share at L >= 95 / 64-px phase (L, ab)", "target": ">= 97 / >= 0.99 / <= 0.05",
                 "measured": f"{invented['empty_min_L']} / {invented['one_point_share_L95']} / "
                             f"{invented['L_locked_64']}, {invented['ab_locked_64']}", "met": invented["met"]})
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", help="ONNX model (default: the shipped one)")
    parser.add_argument("--quick", action="store_true", help="2 textures, 1 realisation x 2 rotations (a smoke run)")
    parser.add_argument("--out", default="out/bench/inference_targets.json")
    args = parser.parse_args(argv)
    model = OnnxModel(args.model, threads=1)
    start = time.perf_counter()
    results = {"model": str(model.path), "load_average": list(os.getloadavg())}
    print("1. textured pictures", flush=True)
    results["textured"] = textured(model, 2 if args.quick else TEXTURE_ITEMS)
    print("2. stationary processes", flush=True)
    results["stationary"] = stationary(model, 1 if args.quick else 2, 2 if args.quick else 4)
    print("3. Poisson stipplings", flush=True)
    results["poisson_white"] = poisson_white(model)
    results["nothing_invented"] = nothing_invented(model)
    results["targets"] = targets(results)
    results["seconds"] = round(time.perf_counter() - start, 1)
    for row in results["targets"]:
        print(f"{'met ' if row['met'] else 'MISS'}  {row['figure']}: {row['measured']} (target {row['target']})")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
