"""Denoising benchmark (``export.density.denoise_density`` as ``infer`` runs it): its noise model and its cost.

1. **Noise model.** On stationary patterns (``patternshop_nn.ood.STATIONARY``, 50,000 points per ink, the
   network's reading calibrated, 8 symmetries) the detail energy ``mean((x - blur(x, s))^2)`` over the
   interior at widths s = 1 ... 16 px, divided by the same for the Poisson bootstrap's noise sample
   (``export.runtime.bootstrap_noise``):

   - Poisson: the network's reading over the sample. Everything in it is noise, so ~1 says the sample
     holds the noise's energy and grain.
   - Poisson-disk and Lloyd: the sharpened L (``export.runtime.refine_density``, no denoising) over the sample. Their
     median over densities and widths is what ``export.density.REGULAR_NOISE_SHARE`` states.

2. **Cost.** ``infer_map`` with and without denoising on a 25,000-point Lloyd stippling of scikit-image's
   ``camera``: median of 3 runs, one thread, 8 and 1 symmetries.

Run with ``make bench`` (or ``python bench/bench_denoise.py [--quick]``); results go to
``out/bench/denoise.json`` with the CPU count and load average.
"""

from __future__ import annotations

import argparse
import os
import statistics

import numpy as np
from scipy.ndimage import gaussian_filter

from common import median_seconds, save_results  # bench/ is on sys.path when run as a script

from data_gen.stipplers import lloyd_stipple
from export.density import REGULAR_NOISE_SHARE
from export.evidence import ScaleChoice
from export.runtime import DEFAULT_MODEL, OnnxModel, bootstrap_noise, infer_map, refine_density
from patternshop_nn.ood import STATIONARY, picture_density, points_per_ink_of
from synthesis.points import PointSet

POINTS_PER_INK = 50_000.0
WIDTHS_PX = (1, 2, 4, 8, 16)
MARGIN_PX = 16


def detail_energy(x: np.ndarray, width: float) -> float:
    """Mean squared detail finer than a Gaussian of ``width`` px over a map's interior."""
    inner = (slice(MARGIN_PX, -MARGIN_PX), slice(MARGIN_PX, -MARGIN_PX))
    return float(np.mean((x - gaussian_filter(x, width))[inner] ** 2))


def noise_model(model: OnnxModel, densities: tuple[float, ...]) -> dict:
    rows, regular_ratios = [], []
    for process in ("poisson", "poisson_disk", "lloyd"):
        for density in densities:
            xy = STATIONARY[process][0](round(density * POINTS_PER_INK), 1000)
            points = PointSet(xy)
            reading = infer_map(points, model, scale=ScaleChoice(POINTS_PER_INK, False), sharpen=False, denoise=False)
            network = reading.lab_map.density().astype(np.float64)
            noise = bootstrap_noise(points, model, network, POINTS_PER_INK)
            measured = network if process == "poisson" else refine_density(points, model, network, POINTS_PER_INK,
                                                                            sharpen=True, denoise=False)[0]
            ratios = [detail_energy(measured, s) / detail_energy(noise, s) for s in WIDTHS_PX]
            if process != "poisson":
                regular_ratios += ratios
            rows.append({"process": process, "density": density, "measured": "network" if process == "poisson" else "sharpened",
                         "energy_ratio_by_width_px": {str(s): round(r, 3) for s, r in zip(WIDTHS_PX, ratios)}})
            print(rows[-1], flush=True)
    return {"rows": rows, "regular_median_ratio": round(statistics.median(regular_ratios), 3),
            "regular_noise_share_used": REGULAR_NOISE_SHARE}


def stippling() -> tuple[PointSet, float]:
    """(a 25,000-point Lloyd stippling, its points per ink) of scikit-image's ``camera`` (a dev dependency)."""
    density, domain = picture_density("camera")
    xy = lloyd_stipple(density, 25_000, domain, iterations=30, seed=0)
    return PointSet(xy, domain), points_per_ink_of(len(xy), density)


def cost(model: OnnxModel, repeats: int) -> dict:
    points, points_per_ink = stippling()
    scale = ScaleChoice(points_per_ink, False)
    timings = {}
    for symmetries in (8, 1):
        for denoise in (False, True):
            seconds, _ = median_seconds(lambda: infer_map(points, model, scale=scale, symmetries=symmetries, denoise=denoise),
                                        repeats=repeats)
            timings[f"symmetries_{symmetries}_denoise_{denoise}"] = round(seconds, 3)
    return {"points": len(points), "median_seconds": timings, "repeats": repeats}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="density 0.5 only, one timing run")
    args = parser.parse_args()
    model = OnnxModel(DEFAULT_MODEL, threads=1)
    results = {"cpu_count": os.cpu_count(), "load_average_before": os.getloadavg()}
    results["noise_model"] = noise_model(model, (0.5,) if args.quick else (0.2, 0.5))
    results["cost"] = cost(model, 1 if args.quick else 3)
    results["load_average_after"] = os.getloadavg()
    save_results("denoise", results)


if __name__ == "__main__":
    main()
