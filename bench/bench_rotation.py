"""Spread of ``analyze``'s decoded colour over rotations and shifts of a stationary pattern (the spread decides whether a pattern keeps its colour when turned).

Each pattern is generated on the unit torus, shifted by a random offset, tiled 3 x 3, rotated about the
centre and cropped to the unit square (so every rotation is a full, non-periodic window of the same process).
The spread is the largest distance of a decoded (a, b) from their mean, in ab units.

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_rotation.py [--points 4096] [--angles 8] [--seeds 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from synthesis.generators import generate
from synthesis.palette import load_palette

PATTERNS = ("perturbed", "jitter", "blue", "red")  # hexagonal lattice with small jitter, jittered grid, Poisson-disk, Thomas


def rotated_window(xy: np.ndarray, angle: float, shift: np.ndarray) -> np.ndarray:
    """Points (n, 2) of a unit-torus pattern shifted by ``shift``, rotated by ``angle`` radians about (0.5, 0.5), in [0, 1)^2."""
    xy = (xy + shift) % 1.0
    tiles = np.concatenate([xy + [dx, dy] for dx in (-1, 0, 1) for dy in (-1, 0, 1)])
    c, s = np.cos(angle), np.sin(angle)
    turned = (tiles - 0.5) @ np.array([[c, s], [-s, c]]) + 0.5
    return turned[np.all((turned >= 0) & (turned < 1), axis=1)]


def spread(colours: np.ndarray) -> float:
    """Largest distance of a colour (k, 2) from their mean, ab units."""
    return float(np.linalg.norm(colours - colours.mean(axis=0), axis=1).max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=4096)
    parser.add_argument("--angles", type=int, default=8, help="rotations from 0 to 90 degrees")
    parser.add_argument("--seeds", type=int, default=2, help="realisations (each with its own random shift)")
    args = parser.parse_args()
    palette = load_palette()
    rng = np.random.default_rng(0)
    angles = np.linspace(0.0, np.pi / 2, args.angles)
    start = time.perf_counter()
    decodes = 0
    for name in PATTERNS:
        colours = []
        for seed in range(args.seeds):
            xy = generate(name, args.points, seed=seed)
            for angle in angles:
                colours.append(palette.decode(rotated_window(xy, angle, rng.random(2))))
                decodes += 1
        colours = np.array(colours)
        mean = colours.mean(axis=0)
        print(f"{name:10s} mean ({mean[0]:6.1f}, {mean[1]:6.1f})  spread {spread(colours):5.1f}  "
              f"nearest preset {palette.nearest_preset(*mean)}", flush=True)
    print(f"{(time.perf_counter() - start) / decodes:.3f} s per decode")


if __name__ == "__main__":
    main()
