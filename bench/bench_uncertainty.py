"""The smoothing tolerance k of ``infer`` for a model with an ``l_scale`` output (``InferConfig.smoothing_tolerance``).

On stationary processes (``patternshop_nn.ood.STATIONARY``: Poisson, Poisson-disk, Lloyd, jittered grid, Thomas; densities
0.05, 0.2 and 0.5 at 50,000 points per ink, seed 1000) the truth is flat, so every change a smoothing makes to the
calibrated density is noise. For each level of the ladder (``export.uncertainty.smoothing_levels``) this measures,
over the map's interior, the change the level makes over the predicted scale b, both averaged in the windows
``export.uncertainty.smooth_by_uncertainty`` uses: its median and 90th percentile. ``flat_tolerance`` is the largest
90th percentile at the widest level over Poisson, Poisson-disk, Lloyd and jitter, over ``1 - smoothing_softness``: at
that k, 90 % of such flat pixels take every level fully, so it bounds k from above (a larger k only smooths more of
what noise does not explain; Thomas clusters are left out: the network reads them as structure). Also reported:
mean |error| / mean b, how far b overstates the calibrated density's error at this scale. ``InferConfig``'s k itself
is chosen below that bound on the development stipplings (``docs/network.md``).

With ``--tolerances K,K,...`` it also scores ``infer``'s maps of the 12 development stipplings (the four development
pictures of ``patternshop_nn.ood`` by its three stipplers, seed 1000) at each k (and unsmoothed): mean SSIM and MAE of L
and the cases better than the oracle KDE in both, the measurement ``InferConfig.smoothing_tolerance`` is set by. Each
k's row also holds every case's SSIM and MAE beside the oracle KDE's (``per_case``); ``--cases`` prints them as a table.

Run with ``python bench/bench_uncertainty.py [--model FILE] [--symmetries N] [--tolerances 0.15,0.25,0.35,0.5] [--cases]``
(default: the shipped model; one without ``l_scale`` is skipped with a note, so ``make bench`` passes); results go
to ``out/bench/uncertainty.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

import numpy as np
from scipy.ndimage import gaussian_filter

from common import save_results  # bench/ is on sys.path when run as a script

from export.evidence import calibrate_density
from export.infer_config import DEFAULT_INFER
from export.runtime import OnnxModel, read_pattern
from export.uncertainty import smoothing_levels, smoothing_window
from patternshop_nn.ood import STATIONARY
from synthesis.conventions import full_ink_points
from synthesis.points import PointSet

POINTS_PER_INK = 50_000.0
DENSITIES = (0.05, 0.2, 0.5)
SEED = 1000
MARGIN_PX = 16
FLAT = ("poisson", "poisson_disk", "lloyd", "jitter")


def ratios(model: OnnxModel, process: str, density: float, symmetries: int) -> dict:
    points = PointSet(STATIONARY[process][0](round(density * POINTS_PER_INK), SEED))
    lab_map, _, _, scale = read_pattern(points, model, POINTS_PER_INK, (256, 256), symmetries)
    ink = len(points) / full_ink_points(POINTS_PER_INK, points.domain)
    calibrated, factor = calibrate_density(lab_map.density().astype(np.float64), ink)
    scale = scale * factor
    inner = (slice(MARGIN_PX, -MARGIN_PX),) * 2
    levels = {}
    for level in smoothing_levels(calibrated.shape):
        window = smoothing_window(level)
        truncate = DEFAULT_INFER.smoothing_window_truncate
        change = gaussian_filter(np.abs(calibrated - gaussian_filter(calibrated, level)), window, truncate=truncate)
        ratio = (change / np.maximum(gaussian_filter(scale, window, truncate=truncate), 1e-12))[inner]
        levels[str(level)] = [round(float(np.median(ratio)), 3), round(float(np.percentile(ratio, 90)), 3)]
    return {"process": process, "density": density, "mean_scale": round(float(scale[inner].mean()), 4),
            "error_over_scale": round(float(np.abs(calibrated - ink)[inner].mean() / scale[inner].mean()), 3),
            "change_over_scale_median_p90": levels}


def development_scores(model: OnnxModel, symmetries: int, tolerances: list[float], print_cases: bool = False) -> list[dict]:
    """Mean SSIM and MAE of L on the 12 development stipplings, and the wins over the oracle KDE, per k (None: unsmoothed),
    each row with its cases (``per_case``: picture, stippler, SSIM, MAE, the oracle KDE's, won); ``print_cases``
    prints them."""
    from data_gen.stipplers import METHODS
    from export.evidence import ScaleChoice
    from export.runtime import infer_map
    from patternshop_nn import ood

    cases = []
    for picture in ood.PICTURES:
        density, domain = ood.picture_density(picture)
        for method in ood.STIPPLERS:
            xy = METHODS[method](density, ood.STIPPLE_POINTS, domain, np.random.default_rng(SEED))
            cases.append((PointSet(xy, domain), density, ood.points_per_ink_of(len(xy), density), f"{picture} {method}"))
    rows, oracle = [], {}
    for tolerance in [None, *tolerances]:
        config = dataclasses.replace(DEFAULT_INFER, symmetries=symmetries, smoothing_tolerance=tolerance or 0.0)
        scores = []
        for k, (points, density, scale, _) in enumerate(cases):
            inference = infer_map(points, model, scale=ScaleChoice(scale, False), denoise=tolerance is not None, config=config)
            truth_L = 100.0 * (1.0 - ood.resample(density, inference.lab_map.L.shape))
            ssim, mae = ood.l_scores(truth_L, inference.lab_map.L.astype(np.float64))
            oracle.setdefault(k, ood.kde_scores(points.xy, truth_L, scale))
            scores.append((ssim, mae, ssim > oracle[k]["kde_ssim"] and mae < oracle[k]["kde_mae"]))
        per_case = [{"case": case[3], "ssim": round(ssim, 4), "mae": round(mae, 3), "oracle_ssim": oracle[k]["kde_ssim"],
                     "oracle_mae": oracle[k]["kde_mae"], "won": bool(won)}
                    for k, (case, (ssim, mae, won)) in enumerate(zip(cases, scores))]
        ssim, mae, wins = np.array(scores).T
        rows.append({"tolerance": tolerance, "mean_ssim": round(float(ssim.mean()), 4), "mean_mae": round(float(mae.mean()), 3),
                     "better_than_oracle_kde": int(wins.sum()), "cases": len(scores)})
        print(rows[-1], flush=True)
        if print_cases:
            for case in per_case:
                print(f"  {case['case']:<28} SSIM {case['ssim']:.3f} (oracle {case['oracle_ssim']:.3f})  MAE {case['mae']:.2f} "
                      f"(oracle {case['oracle_mae']:.2f})  {'won' if case['won'] else 'lost'}", flush=True)
        rows[-1]["per_case"] = per_case
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", help="ONNX model with an l_scale output (default: the shipped one)")
    parser.add_argument("--symmetries", type=int, default=DEFAULT_INFER.symmetries, help="readings averaged (default: infer's)")
    parser.add_argument("--tolerances", type=lambda text: [float(k) for k in text.split(",")], default=[],
                        help="comma-separated k to score on the development stipplings (default: none)")
    parser.add_argument("--cases", action="store_true", help="print every development stippling's scores at each k")
    args = parser.parse_args()
    model = OnnxModel(args.model, threads=1)
    if not model.has_l_scale:
        print(f"bench_uncertainty: skipped: {model.path} has no l_scale output")
        return 0
    rows = [ratios(model, process, density, args.symmetries) for process in STATIONARY for density in DENSITIES]
    widest = str(max(smoothing_levels((256, 256))))
    p90 = max(row["change_over_scale_median_p90"][widest][1] for row in rows if row["process"] in FLAT)
    save_results("uncertainty", {"model": str(model.path), "symmetries": args.symmetries, "load_average": os.getloadavg(),
                                 "rows": rows, "widest_level_p90_flat": p90,
                                 "flat_tolerance": round(p90 / (1.0 - DEFAULT_INFER.smoothing_softness), 3),
                                 "development": development_scores(model, args.symmetries, args.tolerances, args.cases)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
