"""Does a stationary pattern keep its ``analyze`` colour when it is turned or shifted? (issue 28: spread <= 8 ab units)

Processes (generators written here, independent of the palette's corpus): scrambled Sobol points (scipy
``qmc.Sobol(scramble=True)``), a Matérn II hard-core process (radius 0.6 r_max), square and hexagonal lattices
jittered by 5 % of their spacing, Thomas clusters (8 children, sigma 0.3 r_max; ``bench_palette.thomas``). Each realisation is seen at
``--angles`` random rotations, each with a random shift: the toroidal processes are shifted on the torus, tiled
3 x 3, rotated about the centre and cropped to the unit square; the lattices are built directly with rotated,
shifted axes. Every view is a full, non-periodic window of the same process, decoded as ``analyze`` does
(:meth:`synthesis.palette.Palette.locate`).

Figures per process: *rotation spread*, the largest distance of a view's (a, b) from its realisation's mean,
worst realisation (the issue's figure); *seed spread*, the largest distance of a realisation's mean from the
mean of all; the mean colour and its nearest preset. Then the median time of one decode of a 20,000-point
pattern and of the whole ``analyze`` of it.

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_rotation.py [--points 4096] [--angles 6] [--seeds 2] [--out out/bench/rotation.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/ helpers when imported from elsewhere
from bench_palette import _hexagonal_spacing as _r_max  # noqa: E402
from bench_palette import thomas  # noqa: E402
from common import median_seconds  # noqa: E402

from synthesis.palette import load_palette  # noqa: E402

TARGET = 8.0  # ab units
HARD_CORE_RADIUS = 0.6  # r_max
LATTICE_JITTER = 0.05  # lattice spacings

# --- toroidal processes: (about n, 2) points on the unit torus --------------------------------------
def sobol(n: int, rng: np.random.Generator) -> np.ndarray:
    """Owen-scrambled Sobol points (n rounded to a power of two)."""
    from scipy.stats import qmc

    return qmc.Sobol(2, scramble=True, seed=rng).random_base2(round(math.log2(n)))


def hard_core(n: int, rng: np.random.Generator) -> np.ndarray:
    """Matérn II: Poisson points (3 per hard-core disk) with random marks, each dropped if a point with a smaller mark
    lies within the radius (about 0.73 n kept)."""
    radius = HARD_CORE_RADIUS * _r_max(n)
    parents = rng.random((rng.poisson(3.0 / (math.pi * radius**2)), 2))
    marks = rng.random(len(parents))
    pairs = cKDTree(parents, boxsize=1.0).query_pairs(radius, output_type="ndarray")
    beaten = np.zeros(len(parents), bool)
    beaten[np.where(marks[pairs[:, 0]] > marks[pairs[:, 1]], pairs[:, 0], pairs[:, 1])] = True
    return parents[~beaten]


def rotated_window(xy: np.ndarray, angle: float, shift: np.ndarray) -> np.ndarray:
    """Points (n, 2) of a unit-torus pattern shifted by ``shift``, rotated by ``angle`` radians about (0.5, 0.5), in [0, 1)^2."""
    xy = (xy + shift) % 1.0
    tiles = np.concatenate([xy + [dx, dy] for dx in (-1, 0, 1) for dy in (-1, 0, 1)])
    c, s = np.cos(angle), np.sin(angle)
    turned = (tiles - 0.5) @ np.array([[c, s], [-s, c]]) + 0.5
    return turned[np.all((turned >= 0) & (turned < 1), axis=1)]


def toroidal(process: Callable[[int, np.random.Generator], np.ndarray]) -> Callable:
    """A view maker for a toroidal process: ``view(n, rng)`` -> ``turn(angle, shift)`` -> points in [0, 1)^2."""
    def realise(n: int, rng: np.random.Generator) -> Callable[[float, np.ndarray], np.ndarray]:
        xy = process(n, rng)
        return lambda angle, shift: rotated_window(xy, angle, shift)
    return realise


def lattice(hexagonal: bool) -> Callable:
    """A view maker for a jittered lattice of about n points per unit area, built with rotated, shifted axes."""
    def realise(n: int, rng: np.random.Generator) -> Callable[[float, np.ndarray], np.ndarray]:
        spacing = math.sqrt(2.0 / (math.sqrt(3.0) * n)) if hexagonal else 1.0 / math.sqrt(n)
        basis = np.array([[1.0, 0.0], [0.5, math.sqrt(3.0) / 2]] if hexagonal else [[1.0, 0.0], [0.0, 1.0]]) * spacing
        reach = math.ceil(1.5 / (spacing * (math.sqrt(3.0) / 2 if hexagonal else 1.0)))
        i, j = np.meshgrid(np.arange(-reach, reach + 1), np.arange(-reach, reach + 1))
        nodes = np.stack([i.ravel(), j.ravel()], 1) @ basis
        jitter = rng.normal(0.0, LATTICE_JITTER * spacing, nodes.shape)

        def turn(angle: float, shift: np.ndarray) -> np.ndarray:
            c, s = np.cos(angle), np.sin(angle)
            xy = (nodes + shift @ basis) @ np.array([[c, s], [-s, c]]) + jitter + 0.5
            return xy[np.all((xy >= 0) & (xy < 1), axis=1)]
        return turn
    return realise


PROCESSES = {"sobol": toroidal(sobol), "hard-core": toroidal(hard_core), "square lattice": lattice(False),
             "hexagonal lattice": lattice(True), "thomas": toroidal(thomas)}


def spread(colours: np.ndarray) -> float:
    """Largest distance of a colour (k, 2) from their mean, ab units."""
    return float(np.linalg.norm(colours - colours.mean(axis=0), axis=1).max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=4096)
    parser.add_argument("--angles", type=int, default=6, help="random rotations (each with a random shift) per realisation")
    parser.add_argument("--seeds", type=int, default=2, help="realisations per process")
    parser.add_argument("--out", help="write the figures to this JSON file")
    args = parser.parse_args()
    import torch

    from synthesis.analysis import analyze_points
    from synthesis.points import PointSet

    torch.set_num_threads(1)
    palette = load_palette()
    results = {"points": args.points, "angles": args.angles, "seeds": args.seeds, "target": TARGET, "processes": {}}
    for index, (name, realise) in enumerate(PROCESSES.items()):
        rng = np.random.default_rng([index, 28])
        colours = []
        for _ in range(args.seeds):
            turn = realise(args.points, rng)
            colours.append([palette.decode(turn(angle, rng.random(2))) for angle in rng.uniform(0.0, np.pi / 2, args.angles)])
        colours = np.array(colours)
        means = colours.mean(axis=1)
        mean = means.mean(axis=0)
        row = {"rotation_spread": round(max(spread(c) for c in colours), 1), "seed_spread": round(spread(means), 1),
               "mean": np.round(mean, 1).tolist(), "nearest_preset": palette.nearest_preset(*mean),
               "colours": np.round(colours, 1).tolist()}
        results["processes"][name] = row
        print(f"{name:18s} rotation spread {row['rotation_spread']:5.1f}  seed spread {row['seed_spread']:5.1f}  "
              f"mean ({mean[0]:6.1f}, {mean[1]:6.1f})  nearest preset {row['nearest_preset']}", flush=True)
    big = toroidal(hard_core)(20_000, np.random.default_rng(1))(0.3, np.zeros(2))
    results["decode_20k_s"] = round(median_seconds(lambda: palette.decode(big), repeats=3)[0], 3)
    results["analyze_20k_s"] = round(median_seconds(lambda: analyze_points(PointSet(big), palette), repeats=3)[0], 3)
    print(f"20,000 points: decode {results['decode_20k_s']:.3f} s, analyze {results['analyze_20k_s']:.3f} s (median of 3)")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
