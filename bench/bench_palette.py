"""Palette benchmark: is a colour one look, and one look one colour?

``python bench/bench_palette.py [--palette PATH] [--name NAME] [--round-trips K]``
measures a palette asset (default: the shipped one) on patterns from generators
written here, independent of the corpus generators (:mod:`data_gen.families`,
:mod:`synthesis.generators`), and writes ``out/bench/NAME.json``:

* **stability**: Poisson-disk (scipy ``qmc.PoissonDisk``), Lloyd-relaxed
  (weighted Voronoi stippling of a flat density), jittered grid, Poisson and
  Thomas clusters (8 children, sigma 0.3 r_max), 3 seeds x {1,024, 4,096}
  points, decoded on the open unit square (``periodic=False``, as ``analyze``
  does): the largest distance between two of the 6 colours, in ab units.
  Target <= 10 (Thomas <= 20).
* **separation**: the mean colours of Poisson-disk, Lloyd-relaxed, a perturbed
  hexagonal lattice (5 % jitter) and a perfect square lattice, pairwise
  distances. Target >= 15.
* **round trip**: K random colours of the populated region painted as constant
  maps, synthesised (2,048 points) and decoded: median distance to the painted
  colour. Target <= 12 over 50 colours.
* **hue wedge**: the largest share of exemplars in any 60 degree hue wedge
  (target <= 40 %), and the build's recorded stress-1 and trustworthiness
  (targets: no worse than 0.042 and 0.986).
* where every preset lands (a, b, hue, chroma), and the decode time of a
  10,000-point pattern (target <= 1 s).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/ helpers when imported from elsewhere
from common import median_seconds, save_results  # noqa: E402

from synthesis.palette import DEFAULT_PALETTE, Palette, hue_chroma, latent_to_ab  # noqa: E402

SEEDS = (11, 12, 13)
COUNTS = (1024, 4096)
STABILITY_TARGET = {"poisson_disk": 10.0, "lloyd": 10.0, "jittered_grid": 10.0, "poisson": 10.0, "thomas": 20.0}
SEPARATED = ("poisson_disk", "lloyd", "perturbed_lattice", "perfect_lattice")
SEPARATION_TARGET = 15.0
ROUND_TRIP_TARGET = 12.0
ROUND_TRIP_POINTS = 2048
WEDGE_DEGREES = 60
WEDGE_TARGET = 0.40
STRESS_TARGET, TRUST_TARGET = 0.042, 0.986


# --- the bench's own generators: (n, 2) points on the unit square, open domain ---------------
def _hexagonal_spacing(n: int) -> float:
    return math.sqrt(2.0 / (math.sqrt(3.0) * n))


def poisson_disk(n: int, rng: np.random.Generator) -> np.ndarray:
    """scipy's Poisson-disk sampler filled to saturation (about n points)."""
    from data_gen.stipplers import poisson_disk as scipy_poisson_disk

    return scipy_poisson_disk(n, int(rng.integers(2**31)))


def lloyd(n: int, rng: np.random.Generator) -> np.ndarray:
    """Weighted Voronoi stippling of a flat density (40 Lloyd iterations, 16 pixels per point)."""
    from data_gen.stipplers import lloyd_stipple

    side = math.ceil(math.sqrt(16 * n))
    return lloyd_stipple(np.ones((side, side)), n, iterations=40, seed=int(rng.integers(2**31)))


def jittered_grid(n: int, rng: np.random.Generator) -> np.ndarray:
    """One uniform point in each cell of a sqrt(n) x sqrt(n) grid (n a square)."""
    side = math.isqrt(n)
    cells = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)
    return (cells + rng.random(cells.shape)) / side


def poisson(n: int, rng: np.random.Generator) -> np.ndarray:
    return rng.random((n, 2))


def thomas(n: int, rng: np.random.Generator) -> np.ndarray:
    """Thomas process: n/8 uniform parents, 8 Gaussian children each (sigma 0.3 r_max), kept in the square."""
    parents = rng.random((n // 8, 2))
    children = np.repeat(parents, 8, axis=0) + rng.normal(0.0, 0.3 * _hexagonal_spacing(n), (n // 8 * 8, 2))
    return np.mod(children, 1.0)


def perturbed_lattice(n: int, rng: np.random.Generator) -> np.ndarray:
    """Hexagonal lattice of spacing r_max, randomly shifted, each point jittered by 5 % of the spacing."""
    spacing = _hexagonal_spacing(n)
    rows, cols = math.ceil(1.0 / (spacing * math.sqrt(3) / 2)) + 1, math.ceil(1.0 / spacing) + 1
    j, i = np.meshgrid(np.arange(cols), np.arange(rows))
    xy = np.stack([(j + 0.5 * (i % 2)) * spacing, i * spacing * math.sqrt(3) / 2], -1).reshape(-1, 2)
    xy = xy - rng.random(2) * spacing + rng.normal(0.0, 0.05 * spacing, xy.shape)
    return xy[np.all((xy >= 0) & (xy < 1), axis=1)]


def perfect_lattice(n: int, rng: np.random.Generator) -> np.ndarray:
    """Square grid of sqrt(n) x sqrt(n) points, randomly shifted."""
    side = math.isqrt(n)
    cells = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)
    return np.mod(cells + rng.random(2), side) / side


PATTERNS = {"poisson_disk": poisson_disk, "lloyd": lloyd, "jittered_grid": jittered_grid, "poisson": poisson,
            "thomas": thomas, "perturbed_lattice": perturbed_lattice, "perfect_lattice": perfect_lattice}


# --- measurements -------------------------------------------------------------------------
def decoded_colours(palette: Palette) -> dict[str, list[list[float]]]:
    """Pattern name -> the (a, b) decoded for each seed x count."""
    colours = {}
    for name, generator in PATTERNS.items():
        colours[name] = [list(palette.decode(generator(n, np.random.default_rng([seed, n])))) for seed in SEEDS for n in COUNTS]
    return colours


def largest_distance(ab: np.ndarray) -> float:
    """Largest pairwise distance between colours (k, 2)."""
    return float(max(np.linalg.norm(p - q) for p, q in itertools.combinations(ab, 2)))


def round_trip(palette: Palette, colours: int, seed: int = 0) -> dict:
    """Constant maps in random populated colours, synthesised and decoded: distances in ab units."""
    from synthesis.labmap import LabMap
    from synthesis.synthesize import synthesize

    latents = palette.sample_latents(np.random.default_rng(seed), colours)
    painted = np.rint(latent_to_ab(latents))
    distances, seconds = [], 0.0
    for index, (a, b) in enumerate(painted):
        lab = np.broadcast_to(np.array([50.0, a, b], np.float32), (32, 32, 3))
        start = time.perf_counter()
        result = synthesize(LabMap(lab), n=ROUND_TRIP_POINTS, palette=palette, seed=index)
        seconds += time.perf_counter() - start
        decoded = np.array(palette.decode(result.points.xy, result.points.domain))
        distances.append(float(np.linalg.norm(decoded - [a, b])))
    distances = np.array(distances)
    return {"colours": colours, "points": ROUND_TRIP_POINTS, "median": round(float(np.median(distances)), 2),
            "p90": round(float(np.percentile(distances, 90)), 2), "target_median": ROUND_TRIP_TARGET,
            "passed": bool(np.median(distances) <= ROUND_TRIP_TARGET), "synthesis_seconds": round(seconds, 1),
            "painted": painted.tolist(), "distances": distances.round(2).tolist()}


def largest_wedge_share(palette: Palette) -> tuple[float, int]:
    """The largest share of exemplars in a 60-degree hue wedge, and the wedge's start (degrees)."""
    ab = latent_to_ab(palette.exemplar_z)
    hue = np.degrees(np.arctan2(ab[:, 1], ab[:, 0])) % 360.0
    shares = [float(np.mean((hue - start) % 360.0 < WEDGE_DEGREES)) for start in range(360)]
    start = int(np.argmax(shares))
    return shares[start], start


def measure(palette_path: Path, round_trips: int) -> dict:
    """All the figures of the module docstring for one palette asset."""
    import torch

    torch.set_num_threads(1)
    palette = Palette.load(palette_path)
    record_path = palette_path.with_suffix(".json")
    record = json.loads(record_path.read_text()) if record_path.is_file() else {}
    colours = decoded_colours(palette)
    stability = {name: {"spread": round(largest_distance(np.array(colours[name])), 2), "target": target,
                        "passed": largest_distance(np.array(colours[name])) <= target}
                 for name, target in STABILITY_TARGET.items()}
    centres = {name: np.mean(colours[name], axis=0) for name in SEPARATED}
    pairs = {f"{p}-{q}": round(float(np.linalg.norm(centres[p] - centres[q])), 2) for p, q in itertools.combinations(SEPARATED, 2)}
    share, wedge_start = largest_wedge_share(palette)
    metrics = record.get("metrics", {})
    stress = metrics.get("stress1_final", metrics.get("stress1"))
    trust = metrics.get("trustworthiness_final", metrics.get("trustworthiness"))
    presets = {}
    for name, (a, b) in palette.preset_ab().items():
        hue, chroma = hue_chroma(a, b)
        presets[name] = {"a": round(a, 1), "b": round(b, 1), "hue": round(hue, 1), "chroma": round(chroma, 1)}
    blue = PATTERNS["poisson_disk"](10_000, np.random.default_rng(3))
    decode_median, _ = median_seconds(lambda: palette.decode(blue), repeats=3)
    results = {
        "palette": str(palette_path), "exemplars": len(palette.exemplar_z),
        "asset_mb": round(palette_path.stat().st_size / 2**20, 2),
        "stability": stability,
        "separation": {"pairs": pairs, "min": min(pairs.values()), "target": SEPARATION_TARGET,
                       "passed": min(pairs.values()) >= SEPARATION_TARGET},
        "decoded": {name: np.round(ab, 1).tolist() for name, ab in colours.items()},
        "round_trip": round_trip(palette, round_trips) if round_trips else None,
        "hue_wedge": {"largest_share": round(share, 3), "from_degrees": wedge_start, "to_degrees": (wedge_start + WEDGE_DEGREES) % 360,
                      "target": WEDGE_TARGET, "passed": share <= WEDGE_TARGET},
        "layout": {"stress1": stress, "trustworthiness": trust, "targets": [STRESS_TARGET, TRUST_TARGET],
                   "passed": stress is not None and stress <= STRESS_TARGET and trust >= TRUST_TARGET},
        "presets": presets,
        "decode_10k_s": round(decode_median, 3), "decode_10k_target_s": 1.0,
        "build_timings_s": record.get("timings_s"), "build_corpus_exemplars_computed": record.get("corpus_exemplars_computed"),
    }
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--palette", type=Path, default=DEFAULT_PALETTE, help="palette asset (default: the shipped one)")
    parser.add_argument("--name", default="palette", help="results go to out/bench/NAME.json")
    parser.add_argument("--round-trips", type=int, default=50, help="colours in the round trip (0 skips it)")
    args = parser.parse_args(argv)
    save_results(args.name, measure(args.palette, args.round_trips))
    return 0


if __name__ == "__main__":
    sys.exit(main())
