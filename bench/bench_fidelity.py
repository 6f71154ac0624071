"""Fidelity benchmark: is a synthesised pattern a true sample of its map?

Run with ``make bench`` (or ``python bench/bench_fidelity.py [--quick] [--only CASE]``);
results go to ``out/bench/fidelity.json`` (``fidelity_quick.json`` for --quick/--only runs)
and a contact sheet of crops to ``out/bench/fidelity_sheet.png``.

The synthesiser is called only through its public API (``synthesize(lab_map, n=, seed=)``
-> ``.points.xy``), and measured with statistics written independently of its objective
(``bench/fidelity_stats.py``: fine PCF, NN distances, empty circles, strip density
profiles, density PSNR), against reference patterns: each preset's own generator
(torus), scipy's ``qmc.PoissonDisk``, Poisson, and a weighted Lloyd stippler.
The only use of the synthesiser's internals is :func:`objective_score`, which
scores patterns under the synthesiser's *own* objective (objective validity).

Cases (``--only``): ``constant`` (constant maps of each preset, n = 4096),
``edges`` (blue|red and blue|white stripe maps), ``strips`` (every preset: border strips of a constant map and both
sides of the edges of a stripe map with blue, or white for blue; NN CV against the generator's; and both sides of the
density edges of :data:`DENSITY_EDGES`, each in its own local r_max), ``logo``
(examples/logo.tif, default n), ``photos`` (scikit-image's camera, astronaut, moon and coins as ``from-image`` makes them, blue preset,
20,000 points; anchors: weighted Lloyd, 60 iterations, and its capacity-constrained variant CCVT, 50 iterations,
both from a stratified start; ``--photos``, ``--photo-n``, ``--photo-seeds`` to develop on fewer).
Every figure is the median over the seeds (3; 1 with --quick).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fidelity_stats as fs  # noqa: E402
from common import RESULTS_DIR  # noqa: E402

from synthesis.generators import generate  # noqa: E402
from synthesis.labmap import LabMap  # noqa: E402
from synthesis.palette import load_palette  # noqa: E402
from synthesis.synthesize import synthesize  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
PRESETS = ["white", "blue", "green", "red", "step"]
N_CONSTANT = 4096
N_PHOTO = 20000
STRIP_PRESETS = ["white", "blue", "green", "red", "step", "lattice", "lloyd", "matern"]  # every preset of the palette
STRIP_TARGETS = ["white", "blue", "step", "green", "red"]  # strips within 0.8-1.25 (issue 27); the others are reported
STRIP_DEPTH = 3.0  # strips within this many r_max of the border or an edge
# density edges (issue 27, the logo's P counter): stripes (dark preset, L, light preset, L), the dark side first
DENSITY_EDGES = {"blue|blue": ("blue", 15.0, "blue", 76.0), "red|blue": ("red", 15.0, "blue", 76.0)}
CASES = ["constant", "edges", "strips", "logo", "photos"]


# --------------------------------------------------------------------------- the synthesiser, as a user calls it


def run_synthesis(lab: np.ndarray, n: int | None, seed: int) -> tuple[np.ndarray, float]:
    """Points (n, 2) for a CIELAB array through the public API, and the wall time."""
    start = time.perf_counter()
    result = synthesize(LabMap(lab.astype(np.float32)), n=n, seed=seed)
    return np.asarray(result.points.xy, np.float64), time.perf_counter() - start


def domain_of(lab: np.ndarray) -> tuple[float, float]:
    H, W = lab.shape[:2]
    side = max(H, W)
    return W / side, H / side


def density_of(lab: np.ndarray) -> np.ndarray:
    return 1.0 - np.asarray(lab[..., 0], np.float64) / 100.0


def objective_score(lab: np.ndarray, xy: np.ndarray) -> float | None:
    """The synthesiser's own objective for ``xy`` on the map (lower is better to *it*).

    The one place that touches the synthesiser's internals; re-point it when that API changes.
    Today: ``final_loss(MapFields.build(map, n, palette), xy)`` with every point a centre.
    """
    try:
        from synthesis.fields import MapFields
        from synthesis.synthesize import final_loss

        fields = MapFields.build(LabMap(lab.astype(np.float32)), len(xy), load_palette())
        try:
            return float(final_loss(fields, torch.from_numpy(np.asarray(xy, np.float32))))
        except Exception:  # newer API: a numpy array
            return float(final_loss(fields, np.asarray(xy, np.float64)))
    except Exception as error:  # noqa: BLE001 - a missing objective must not stop the bench
        print(f"objective_score unavailable: {error!r}", flush=True)
        return None


def constant_lab(ab: tuple[float, float], size: int = 64, L: float = 50.0) -> np.ndarray:
    lab = np.zeros((size, size, 3), np.float32)
    lab[..., 0] = L
    lab[..., 1:] = ab
    return lab


def median(values):
    values = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    return float(statistics.median(values)) if values else None


def medians(rows: list[dict]) -> dict:
    out = {}
    for key in rows[0]:
        if all(isinstance(row.get(key), (int, float)) and not isinstance(row.get(key), bool) for row in rows):
            out[key] = median([row[key] for row in rows])
    return out


def r4(x):
    return None if x is None else round(float(x), 4)


# --------------------------------------------------------------------------- cases


def case_constant(seeds: list[int], keep: dict) -> dict:
    presets = load_palette().preset_ab()
    out: dict = {}
    for name in PRESETS:
        lab = constant_lab(presets[name])
        domain = domain_of(lab)
        rows = []
        for seed in seeds:
            xy, seconds = run_synthesis(lab, N_CONSTANT, seed)
            gen_a = generate(name, N_CONSTANT, 1000 + seed)
            gen_b = generate(name, N_CONSTANT, 2000 + seed)
            intensity = fs.Intensity.constant(N_CONSTANT, domain)
            synth_nn = fs.nn_stats(xy, intensity)
            gen_nn = fs.nn_stats(gen_a, intensity, periodic=True)
            gen_nn_b = fs.nn_stats(gen_b, intensity, periodic=True)
            # the generator's reference shares: mean of its two realisations (a single one is noisy: ~20-40 stacked points)
            gen_stacked = 0.5 * (gen_nn["stacked_fraction"] + gen_nn_b["stacked_fraction"])
            gen_cv = 0.5 * (gen_nn["nn_cv"] + gen_nn_b["nn_cv"])
            r, g_synth = fs.pcf(xy, domain)
            _, g_a = fs.pcf(gen_a, domain, periodic=True)
            _, g_b = fs.pcf(gen_b, domain, periodic=True)
            d_sg, d_gg = fs.pcf_distance(g_synth, g_a), fs.pcf_distance(g_a, g_b)
            synth_lec = fs.empty_circles(xy, intensity)
            gen_lec = fs.empty_circles(gen_a, intensity, periodic=True)
            _, border_synth = fs.border_profile(xy, domain, N_CONSTANT)
            _, border_gen = fs.border_profile(gen_a, domain, N_CONSTANT)  # torus pattern seen through the square
            loss_synth, loss_gen = objective_score(lab, xy), objective_score(lab, gen_a)
            row = {
                "seed": seed, "synth_seconds": seconds,
                "stacked_fraction": synth_nn["stacked_fraction"], "gen_stacked_fraction": gen_stacked,
                "min_nn": synth_nn["min_nn"], "gen_min_nn": min(gen_nn["min_nn"], gen_nn_b["min_nn"]),
                "nn_cv": synth_nn["nn_cv"], "gen_nn_cv": gen_cv, "nn_cv_ratio": synth_nn["nn_cv"] / gen_cv,
                "pcf_dist_synth_gen": d_sg, "pcf_dist_gen_gen": d_gg, "pcf_ratio": d_sg / d_gg,
                "largest_empty_circle": synth_lec["largest"], "gen_largest_empty_circle": gen_lec["largest"],
                "holes_over_1": synth_lec["holes"], "gen_holes_over_1": gen_lec["holes"],
                "border_min": float(border_synth.min()), "border_max": float(border_synth.max()),
                "border_first_strip": float(border_synth[0]),
                "gen_border_min": float(border_gen.min()), "gen_border_max": float(border_gen.max()),
                "objective_synth": loss_synth, "objective_gen": loss_gen,
                "objective_gen_over_synth": (loss_gen / loss_synth) if loss_synth and loss_gen is not None else None,
                "border_profile": [r4(v) for v in border_synth],
            }
            rows.append(row)
            print(f"constant {name} seed {seed}: " + json.dumps({k: r4(v) if isinstance(v, float) else v
                                                               for k, v in row.items() if k != "border_profile"}), flush=True)
            if seed == seeds[0]:
                keep[f"constant_{name}"] = {"synth": xy, "gen": gen_a, "domain": domain}
                keep.setdefault("pcf", {})[name] = {"r": r, "synth": g_synth, "gen": g_a, "gen2": g_b}
        out[name] = {"median": medians(rows), "per_seed": rows,
                     "pcf_seed0": {"r": [r4(v) for v in keep["pcf"][name]["r"]],
                                   "synth": [r4(v) for v in keep["pcf"][name]["synth"]],
                                   "gen": [r4(v) for v in keep["pcf"][name]["gen"]]}}
    # bounded / unstructured references at the same n, for the blue rows
    refs = []
    for seed in seeds:
        pd = fs.poisson_disk(N_CONSTANT, seed)
        po = np.random.default_rng(3000 + seed).random((N_CONSTANT, 2))
        blue_gen = generate("blue", N_CONSTANT, 1000 + seed)
        row = {"seed": seed}
        for label, pts in (("poisson_disk", pd), ("poisson", po)):
            intensity = fs.Intensity.constant(len(pts))
            nn = fs.nn_stats(pts, intensity)
            lec = fs.empty_circles(pts, intensity)
            _, border = fs.border_profile(pts, (1.0, 1.0), len(pts))
            _, g = fs.pcf(pts)
            _, g_blue = fs.pcf(blue_gen, periodic=True)
            row.update({f"{label}_n": len(pts), f"{label}_stacked_fraction": nn["stacked_fraction"], f"{label}_min_nn": nn["min_nn"],
                        f"{label}_nn_cv": nn["nn_cv"], f"{label}_largest_empty_circle": lec["largest"],
                        f"{label}_border_min": float(border.min()), f"{label}_border_max": float(border.max()),
                        f"{label}_pcf_dist_to_blue_gen": fs.pcf_distance(g, g_blue)})
        refs.append(row)
        print(f"references seed {seed}: " + json.dumps({k: r4(v) for k, v in row.items()}), flush=True)
    out["references"] = {"median": medians(refs), "per_seed": refs,
                         "note": "poisson_disk: scipy qmc.PoissonDisk fill_space at 0.725 r_max (bounded unit square, about n points); "
                                 "poisson: n uniform points in the unit square"}
    return out


def stripe_lab(left_ab, right_ab, stripe_px: int = 16, size=(64, 128), L: float = 50.0,
               right_L: float | None = None) -> np.ndarray:
    """Vertical stripes ``stripe_px`` wide alternating left_ab (first) and right_ab, L (the right stripes: ``right_L``
    if given)."""
    H, W = size
    lab = np.zeros((H, W, 3), np.float32)
    lab[..., 0] = L
    stripe = (np.arange(W) // stripe_px) % 2
    if right_L is not None:
        lab[:, stripe == 1, 0] = right_L
    lab[:, stripe == 0, 1:] = left_ab
    lab[:, stripe == 1, 1:] = right_ab
    return lab


def stripe_edge_distances(xy: np.ndarray, lab: np.ndarray, stripe_px: int, unit: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Of the points xy (n, 2) farther than 2 ``unit`` from the top/bottom border of a map of vertical stripes
    ``stripe_px`` wide: their distances (k,) to the nearest stripe edge, whether each lies on the first colour's side
    (k,) bool, and the number of edges."""
    w, h = domain_of(lab)
    width = stripe_px * w / lab.shape[1]
    edges = np.arange(1, lab.shape[1] // stripe_px) * width
    x, y = xy[:, 0], xy[:, 1]
    x = x[(y > 2 * unit) & (y < h - 2 * unit)]
    distance = np.abs(x - edges[np.argmin(np.abs(x[:, None] - edges[None]), axis=1)])
    return distance, (np.floor(x / width).astype(int) % 2) == 0, len(edges)


def edge_profile(xy: np.ndarray, lab: np.ndarray, stripe_px: int, n: int, reach: float = 4.0):
    """Strip counts against the signed distance to the nearest stripe edge (negative on the first
    colour's side), points within 2 r_max of the top/bottom border left out; ratio to expected."""
    w, h = domain_of(lab)
    unit = fs.r_max(n, w * h)
    distance, first_colour, count = stripe_edge_distances(xy, lab, stripe_px, unit)
    per_unit = n / (w * h) * (h - 4 * unit) * count
    return fs.strip_profile(np.where(first_colour, -distance, distance), per_unit, unit, -reach, reach)


def density_edge_profile(xy: np.ndarray, lab: np.ndarray, stripe_px: int, n: int, reach: float = STRIP_DEPTH):
    """Strip counts on both sides of the edges of a stripe map whose two colours differ in density, each side in strips
    0.5 of its own local r_max wide, against that side's expected count (map ink x points per ink); points within 2 mean
    r_max of the top/bottom border left out. Returns (strip centres in the side's r_max, first colour's ratios (nearest
    the edge first), second colour's ratios)."""
    w, h = domain_of(lab)
    unit = fs.r_max(n, w * h)
    density = density_of(lab)
    intensity = n * density / (density.mean() * w * h)  # points per unit area of each pixel
    distance, first_colour, count = stripe_edge_distances(xy, lab, stripe_px, unit)
    sides = []
    for side, column in ((first_colour, 0), (~first_colour, stripe_px)):
        own = float(intensity[0, column])
        side_unit = float(fs.r_max_of_intensity(own))
        centres, ratio = fs.strip_profile(distance[side], own * (h - 4 * unit) * count, side_unit, 0.0, reach)
        sides.append(ratio)
    return centres, sides[0], sides[1]


def density_edge_generator(lab: np.ndarray, stripe_px: int, n: int, dark: str, light: str, seed: int) -> np.ndarray:
    """A true sample of a density-edge stripe map: each side cut from its preset's generator (torus) at its own intensity."""
    w, h = domain_of(lab)
    width = stripe_px * w / lab.shape[1]
    density = density_of(lab)
    out = []
    for k, (name, column) in enumerate(((dark, 0), (light, stripe_px))):
        count = int(round(n * density[0, column] / (density.mean() * w * h)))  # points of the side's density in [0, 1)^2
        points = generate(name, count, 2000 + 10 * seed + k)
        points = points[points[:, 1] < h]
        out.append(points[(np.floor(points[:, 0] / width).astype(int) % 2) == k])
    return np.concatenate(out)


def case_density_edges(seeds: list[int], names: list[str]) -> dict:
    """Both sides of the density edges of :data:`DENSITY_EDGES` (64x128 maps of 16 px stripes, n = :data:`N_CONSTANT`):
    strips 0.5 local r_max wide within :data:`STRIP_DEPTH` local r_max, ratios to the expected density, profiles pooled
    over the seeds; yardstick: each side cut from its generator."""
    presets = load_palette().preset_ab()
    n, stripe_px = N_CONSTANT, 16
    out: dict = {}
    for key in names:
        dark, dark_L, light, light_L = DENSITY_EDGES[key]
        lab = stripe_lab(presets[dark], presets[light], stripe_px, L=dark_L, right_L=light_L)
        synth, gen = [], []
        for seed in seeds:
            xy, _ = run_synthesis(lab, n, seed)
            centres, *sides = density_edge_profile(xy, lab, stripe_px, n)
            synth.append(sides)
            sample = density_edge_generator(lab, stripe_px, n, dark, light, seed)
            gen.append(density_edge_profile(sample, lab, stripe_px, len(sample))[1:])
        synth, gen = np.mean(synth, axis=0), np.mean(gen, axis=0)  # (2 sides, strips)
        row = {"dark": f"{dark} L {dark_L:g}", "light": f"{light} L {light_L:g}",
               "dark_min": float(synth[0].min()), "dark_max": float(synth[0].max()),
               "light_min": float(synth[1].min()), "light_max": float(synth[1].max()),
               "gen_min": float(gen.min()), "gen_max": float(gen.max()),
               "dark_profile": [r4(v) for v in synth[0]], "light_profile": [r4(v) for v in synth[1]],
               "gen_dark_profile": [r4(v) for v in gen[0]], "gen_light_profile": [r4(v) for v in gen[1]]}
        print(f"density edge {dark} L {dark_L:g} | {light} L {light_L:g}: dark side from the edge {np.round(synth[0], 2).tolist()}, "
              f"light side {np.round(synth[1], 2).tolist()} (generator {gen.min():.2f}..{gen.max():.2f})", flush=True)
        out[key] = row
    return out


def case_edges(seeds: list[int], pairs: list[str], keep: dict) -> dict:
    presets = load_palette().preset_ab()
    n, stripe_px = 4096, 16
    out: dict = {}
    for other in pairs:
        lab = stripe_lab(presets["blue"], presets[other], stripe_px)
        rows = []
        for seed in seeds:
            xy, seconds = run_synthesis(lab, n, seed)
            centres, ratio = edge_profile(xy, lab, stripe_px, n)
            poisson = np.random.default_rng(4000 + seed).random((n, 2)) * domain_of(lab)
            _, ratio_poisson = edge_profile(poisson, lab, stripe_px, n)
            near = np.abs(centres) < 3.0
            w, h = domain_of(lab)
            _, border = fs.border_profile(xy, (w, h), n)
            rows.append({"seed": seed, "synth_seconds": seconds,
                         "edge_min": float(ratio[near].min()), "edge_max": float(ratio[near].max()),
                         "poisson_edge_min": float(ratio_poisson[near].min()), "poisson_edge_max": float(ratio_poisson[near].max()),
                         "border_min": float(border.min()), "border_max": float(border.max()),
                         "profile": [r4(v) for v in ratio]})
            print(f"edges blue|{other} seed {seed}: min {ratio[near].min():.3f} max {ratio[near].max():.3f} "
                  f"(poisson {ratio_poisson[near].min():.3f}-{ratio_poisson[near].max():.3f}) profile {np.round(ratio, 2).tolist()}", flush=True)
            if seed == seeds[0]:
                keep[f"edge_{other}"] = {"synth": xy, "domain": domain_of(lab), "lab": lab}
        profile = np.median(np.array([row["profile"] for row in rows]), axis=0)
        out[f"blue|{other}"] = {"median": medians(rows), "per_seed": rows, "strip_centres_r_max": [r4(c) for c in centres],
                                "median_profile": [r4(v) for v in profile],
                                "setup": f"64x128 map, stripes {stripe_px} px (~{stripe_px / 128 / fs.r_max(n, 0.5):.1f} r_max) alternating blue "
                                         f"and {other}, L = 50, n = {n}; 7 edges; strips 0.5 r_max wide, negative = blue side; "
                                         "min/max over strips within 3 r_max of the edge; points within 2 r_max of top/bottom left out"}
    return out


def strip_partner(name: str) -> str:
    """The preset across the correlation edges of ``name``'s stripe map: blue (blue's own: white)."""
    return "white" if name == "blue" else "blue"


def case_strips(seeds: list[int], names: list[str]) -> dict:
    """Border and correlation-edge strips (0.5 r_max wide, within :data:`STRIP_DEPTH` r_max) of each preset, as ratios to
    the expected density, profiles pooled over the seeds: the border of a constant map (n = :data:`N_CONSTANT`) and both
    sides of the edges of a map of stripes preset | :func:`strip_partner` (as ``case_edges``). Noise yardstick: the preset's
    generator (torus) seen through the same strips. Also the constant map's NN CV / the generator's."""
    presets = load_palette().preset_ab()
    n, stripe_px = N_CONSTANT, 16
    out: dict = {}
    for name in names:
        partner = strip_partner(name)
        lab = constant_lab(presets[name])
        stripes = stripe_lab(presets[name], presets[partner], stripe_px)
        border, gen_border, edge, gen_edge, cv_ratio = [], [], [], [], []
        for seed in seeds:
            xy, _ = run_synthesis(lab, n, seed)
            gen = generate(name, n, 1000 + seed)
            border.append(fs.border_profile(xy, (1.0, 1.0), n, depth=STRIP_DEPTH)[1])
            gen_border.append(fs.border_profile(gen, (1.0, 1.0), n, depth=STRIP_DEPTH)[1])
            intensity = fs.Intensity.constant(n)
            gen_cv = fs.nn_stats(gen, intensity, periodic=True)["nn_cv"]
            if gen_cv > 1e-3:  # a lattice's NN distances do not vary
                cv_ratio.append(fs.nn_stats(xy, intensity)["nn_cv"] / gen_cv)
            xy, _ = run_synthesis(stripes, n, seed)
            centres, ratio = edge_profile(xy, stripes, stripe_px, n, STRIP_DEPTH)
            edge.append(ratio)
            half = gen[gen[:, 1] < 0.5]  # the generator's torus pattern through a window of the stripe map's shape
            gen_edge.append(edge_profile(half, stripes, stripe_px, len(half), STRIP_DEPTH)[1])
        border, gen_border = np.mean(border, axis=0), np.mean(gen_border, axis=0)
        edge, gen_edge = np.mean(edge, axis=0), np.mean(gen_edge, axis=0)
        own = centres < 0
        row = {"partner": partner, "border_min": float(border.min()), "border_max": float(border.max()),
               "gen_border_min": float(gen_border.min()), "gen_border_max": float(gen_border.max()),
               "edge_min": float(edge[own].min()), "edge_max": float(edge[own].max()),
               "partner_edge_min": float(edge[~own].min()), "partner_edge_max": float(edge[~own].max()),
               "gen_edge_min": float(gen_edge.min()), "gen_edge_max": float(gen_edge.max()),
               "nn_cv_ratio": median(cv_ratio), "border_profile": [r4(v) for v in border], "edge_profile": [r4(v) for v in edge]}
        print(f"strips {name}: border {np.round(border, 2).tolist()} (generator {gen_border.min():.2f}..{gen_border.max():.2f}); "
              f"{name}|{partner} edge {np.round(edge, 2).tolist()} (generator {gen_edge.min():.2f}..{gen_edge.max():.2f}); "
              f"NN CV ratio {row['nn_cv_ratio']}", flush=True)
        out[name] = row
    out["setup"] = (f"border: constant map, n = {n}, rings 0.5 r_max wide at 0-{STRIP_DEPTH:g} r_max from the border; edges: 64x128 "
                    f"map of {stripe_px} px stripes preset | partner, L = 50, n = {n}, strips 0.5 r_max wide within {STRIP_DEPTH:g} "
                    f"r_max of the 7 edges, negative = the preset's side; profiles are means over {len(seeds)} seeds")
    return out


def case_logo(seeds: list[int]) -> dict:
    from synthesis.mapio import read_map

    lab = np.asarray(read_map(REPO / "examples" / "logo.tif").lab, np.float64)
    domain = domain_of(lab)
    rows = []
    for seed in seeds:
        xy, seconds = run_synthesis(lab, None, seed)
        intensity = fs.Intensity(density_of(lab), domain, len(xy))
        nn = fs.nn_stats(xy, intensity)
        exact = int(np.sum(fs.nearest_neighbours(xy, domain) < 1e-5))
        lec = fs.empty_circles(xy, intensity)
        rows.append({"seed": seed, "n": len(xy), "synth_seconds": seconds, "stacked_fraction": nn["stacked_fraction"],
                     "stacked_count": nn["stacked_count"], "within_1e-5": exact,
                     "largest_empty_circle": lec["largest"], "holes_over_1": lec["holes"]})
        print(f"logo seed {seed}: {json.dumps({k: r4(v) for k, v in rows[-1].items()})}", flush=True)
    return {"median": medians(rows), "per_seed": rows}


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def photo_lab(name: str, ab: tuple[float, float]) -> np.ndarray:
    """L = 100 Y with Y the linear luminance (sRGB decoded; 0.2126, 0.7152, 0.0722), constant ab."""
    from skimage import data

    image = getattr(data, name)()
    if image.ndim == 2:
        Y = srgb_to_linear(image)
    else:
        lin = srgb_to_linear(image[..., :3])
        Y = lin @ np.array([0.2126, 0.7152, 0.0722])
    lab = np.zeros(Y.shape + (3,), np.float32)
    lab[..., 0] = 100.0 * Y
    lab[..., 1:] = ab
    return lab


def photo_metrics(pts: np.ndarray, density: np.ndarray, domain: tuple[float, float], intensity: fs.Intensity) -> dict:
    """Tone and holes of a stipple: density PSNR at blurs of 1, 2 and 4 mean spacings, the largest empty circle where
    the density is >= 0.15 (local r_max), holes over 1 local r_max, stacked share."""
    lec = fs.empty_circles(pts, intensity)
    nn = fs.nn_stats(pts, intensity)
    return {"psnr_1": fs.density_psnr(pts, density, domain, 1.0), "psnr_2": fs.density_psnr(pts, density, domain, 2.0),
            "psnr_4": fs.density_psnr(pts, density, domain, 4.0),
            "largest_empty_circle": lec["largest"], "holes_over_1": lec["holes"], "stacked_fraction": nn["stacked_fraction"],
            "min_nn": nn["min_nn"]}


def case_photos(seeds: list[int], names: list[str], keep: dict, n: int = N_PHOTO) -> dict:
    """``from-image`` maps (L = 100 Y, the blue preset) of the development pictures at n points: the synthesiser
    against two anchors from the same stratified start, weighted Lloyd (:data:`LLOYD_ITERATIONS` iterations) and
    its capacity-constrained variant (:func:`data_gen.stipplers.capacity_lloyd_stipple`, :data:`CCVT_ITERATIONS`)."""
    from data_gen.stipplers import capacity_lloyd_stipple

    blue = load_palette().preset_ab()["blue"]
    out: dict = {}
    for name in names:
        lab = photo_lab(name, blue)
        domain = domain_of(lab)
        density = density_of(np.asarray(LabMap(lab).lab, np.float64))  # after the map's own clipping
        intensity = fs.Intensity(density, domain, n)
        rows = []
        for seed in seeds:
            xy, seconds = run_synthesis(lab, n, seed)
            start = time.perf_counter()
            lloyd = fs.lloyd_stipple(density, n, domain, iterations=LLOYD_ITERATIONS, seed=seed)
            lloyd_seconds = time.perf_counter() - start
            start = time.perf_counter()
            ccvt, spread = capacity_lloyd_stipple(density, n, domain, iterations=CCVT_ITERATIONS, balance=CCVT_BALANCE, seed=seed)
            ccvt_seconds = time.perf_counter() - start
            row = {"seed": seed, "n": n, "synth_seconds": seconds, "lloyd_seconds": lloyd_seconds, "ccvt_seconds": ccvt_seconds,
                   "ccvt_capacity_spread": spread}
            for label, pts in (("synth", xy), ("lloyd", lloyd), ("ccvt", ccvt)):
                row.update({f"{label}_{key}": value for key, value in photo_metrics(pts, density, domain, intensity).items()})
            for blur in (1, 2, 4):
                row[f"psnr_{blur}_vs_lloyd"] = row[f"synth_psnr_{blur}"] - row[f"lloyd_psnr_{blur}"]
                row[f"psnr_{blur}_vs_ccvt"] = row[f"synth_psnr_{blur}"] - row[f"ccvt_psnr_{blur}"]
            rows.append(row)
            print(f"photo {name} seed {seed}: {json.dumps({k: r4(v) for k, v in row.items()})}", flush=True)
            if seed == seeds[0]:
                keep[f"photo_{name}"] = {"synth": xy, "lloyd": lloyd, "ccvt": ccvt, "domain": domain, "density": density}
        out[name] = {"median": medians(rows), "per_seed": rows,
                     "setup": f"{lab.shape[1]}x{lab.shape[0]} map, L = 100 Y (linear luminance, as from-image), blue ab, n = {n}; "
                              f"Lloyd: {LLOYD_ITERATIONS} iterations on the pixel grid from a stratified start; CCVT: "
                              f"{CCVT_ITERATIONS} iterations of {CCVT_BALANCE} capacity balancings then centroids, same start"}
    return out


LLOYD_ITERATIONS = 60
CCVT_ITERATIONS = 50  # capacity spread (max |m_i n - 1|) about 0.3 at 20k points on 512^2 (pixel-discrete); PSNR flat after ~30
CCVT_BALANCE = 2
PHOTOS = ["camera", "astronaut", "moon", "coins"]  # development pictures only (other scikit-image pictures are unseen checks)


# --------------------------------------------------------------------------- targets


def target_rows(results: dict) -> list[dict]:
    rows: list[dict] = []

    def add(target, measured, criterion, ok, reference=None):
        rows.append({"target": target, "measured": r4(measured) if isinstance(measured, (int, float)) else measured,
                     "reference": reference, "criterion": criterion,
                     "pass": None if ok is None else bool(ok)})

    def within(x, lo, hi):
        return None if x is None else lo <= x <= hi

    const = results.get("constant")
    if const:
        refs = const["references"]["median"]
        for name in PRESETS:
            m = const[name]["median"]
            if name in ("blue", "step"):
                add(f"stacked fraction, constant {name}", m["stacked_fraction"], "== 0", m["stacked_fraction"] == 0,
                    f"generator {m['gen_stacked_fraction']:.4f}")
            else:
                limit = 1.5 * m["gen_stacked_fraction"]
                add(f"stacked fraction, constant {name}", m["stacked_fraction"], f"<= 1.5 x generator = {limit:.4f}",
                    m["stacked_fraction"] <= limit, f"generator {m['gen_stacked_fraction']:.4f}")
        m = const["blue"]["median"]
        add("blue: min NN (r_max)", m["min_nn"], ">= 0.6", m["min_nn"] >= 0.6,
            f"generator {m['gen_min_nn']:.3f}, PoissonDisk {refs['poisson_disk_min_nn']:.3f}")
        add("blue: largest empty circle, constant map (r_max)", m["largest_empty_circle"], "<= 1.2",
            m["largest_empty_circle"] <= 1.2,
            f"generator {m['gen_largest_empty_circle']:.3f}, PoissonDisk {refs['poisson_disk_largest_empty_circle']:.3f}, "
            f"Poisson {refs['poisson_largest_empty_circle']:.3f}")
        for name in PRESETS:
            m = const[name]["median"]
            add(f"{name}: fine-PCF distance to generator / generator-generator", m["pcf_ratio"], "<= 1.5", m["pcf_ratio"] <= 1.5,
                f"d(synth,gen) {m['pcf_dist_synth_gen']:.3f}, d(gen,gen) {m['pcf_dist_gen_gen']:.3f}")
        for name in PRESETS:
            m = const[name]["median"]
            add(f"{name}: NN CV / generator's", m["nn_cv_ratio"], "0.85-1.15", within(m["nn_cv_ratio"], 0.85, 1.15),
                f"synth {m['nn_cv']:.3f}, generator {m['gen_nn_cv']:.3f}")
        for name in PRESETS:
            m = const[name]["median"]
            ratio = m.get("objective_gen_over_synth")
            add(f"{name}: objective validity, generator loss / synthesised loss", ratio, "<= 2",
                None if ratio is None else ratio <= 2,
                None if m.get("objective_synth") is None else f"synth {m['objective_synth']:.4g}, generator {m['objective_gen']:.4g}")
        for name in PRESETS:
            m = const[name]["median"]
            add(f"{name}: border strips (0-3 r_max) min..max / expected", f"{m['border_min']:.3f}..{m['border_max']:.3f}",
                "within 0.75-1.3", within(m["border_min"], 0.75, 1.3) and within(m["border_max"], 0.75, 1.3),
                f"generator window {m['gen_border_min']:.2f}..{m['gen_border_max']:.2f}"
                + (f"; PoissonDisk {refs['poisson_disk_border_min']:.2f}..{refs['poisson_disk_border_max']:.2f}" if name in ("blue", "step") else ""))
    edges = results.get("edges")
    if edges:
        for key, value in edges.items():
            if not isinstance(value, dict):
                continue
            m = value["median"]
            add(f"{key} edge strips (within 3 r_max) min..max / expected", f"{m['edge_min']:.3f}..{m['edge_max']:.3f}",
                "within 0.75-1.3", within(m["edge_min"], 0.75, 1.3) and within(m["edge_max"], 0.75, 1.3),
                f"Poisson {m['poisson_edge_min']:.2f}..{m['poisson_edge_max']:.2f}")
    strips = results.get("strips")
    if strips:
        for name, m in strips.items():
            if not isinstance(m, dict) or name == "density_edges":
                continue
            for label, lo, hi, reference in (
                    ("border", m["border_min"], m["border_max"], f"generator {m['gen_border_min']:.2f}..{m['gen_border_max']:.2f}"),
                    (f"{name}|{m['partner']} edge, {name} side", m["edge_min"], m["edge_max"],
                     f"generator {m['gen_edge_min']:.2f}..{m['gen_edge_max']:.2f}"),
                    (f"{name}|{m['partner']} edge, {m['partner']} side", m["partner_edge_min"], m["partner_edge_max"], None)):
                ok = within(lo, 0.8, 1.25) and within(hi, 0.8, 1.25)
                add(f"{name}: {label} strips (0-3 r_max) min..max / expected", f"{lo:.3f}..{hi:.3f}", "within 0.8-1.25",
                    ok if name in STRIP_TARGETS or label.endswith(f"{m['partner']} side") else None, reference)
            if name in ("green", "red", "matern"):
                add(f"{name}: NN CV / generator's (strips case)", m["nn_cv_ratio"], "0.85-1.15",
                    within(m["nn_cv_ratio"], 0.85, 1.15) if name != "matern" else None)
        for m in strips.get("density_edges", {}).values():
            for side in ("dark", "light"):
                lo, hi = m[f"{side}_min"], m[f"{side}_max"]
                add(f"density edge {m['dark']} | {m['light']}, {m[side]} side strips (0-3 local r_max) min..max / expected",
                    f"{lo:.3f}..{hi:.3f}", "within 0.8-1.25", within(lo, 0.8, 1.25) and within(hi, 0.8, 1.25),
                    f"generator {m['gen_min']:.2f}..{m['gen_max']:.2f}")
    logo = results.get("logo")
    if logo:
        m = logo["median"]
        add("logo (default n): stacked fraction", m["stacked_fraction"], "<= 0.005", m["stacked_fraction"] <= 0.005,
            f"{m['stacked_count']:.0f} of {m['n']:.0f} points; {m['within_1e-5']:.0f} within 1e-5")
    photos = results.get("photos")
    if photos:
        for name, value in photos.items():
            if not isinstance(value, dict):
                continue
            m = value["median"]
            for blur in (1, 2):
                d = m[f"psnr_{blur}_vs_lloyd"]
                add(f"{name}: density PSNR, blur {blur} spacing(s), synth - Lloyd (dB)", d, ">= -1", d >= -1,
                    f"synth {m[f'synth_psnr_{blur}']:.2f} dB, Lloyd {m[f'lloyd_psnr_{blur}']:.2f} dB, "
                    f"CCVT {m[f'ccvt_psnr_{blur}']:.2f} dB")
            add(f"{name}: largest empty circle, density >= 0.15 (local r_max)", m["synth_largest_empty_circle"], "<= 1.1",
                m["synth_largest_empty_circle"] <= 1.1,
                f"holes > 1 r_max: {m['synth_holes_over_1']:.0f}; Lloyd {m['lloyd_largest_empty_circle']:.3f} "
                f"({m['lloyd_holes_over_1']:.0f} holes), CCVT {m['ccvt_largest_empty_circle']:.3f}")
    return rows


def print_table(rows: list[dict]) -> None:
    width = max(len(row["target"]) for row in rows)
    print(f"\n{'target':<{width}}  {'measured':>14}  {'criterion':<28}  {'pass':<5}  reference")
    for row in rows:
        verdict = "-" if row["pass"] is None else ("PASS" if row["pass"] else "FAIL")
        measured = row["measured"] if isinstance(row["measured"], str) else f"{row['measured']}"
        print(f"{row['target']:<{width}}  {measured:>14}  {row['criterion']:<28}  {verdict:<5}  {row['reference'] or ''}")
    passed = sum(1 for row in rows if row["pass"])
    print(f"\n{passed} of {sum(1 for row in rows if row['pass'] is not None)} targets met", flush=True)


# --------------------------------------------------------------------------- contact sheet


def _render(xy, window, size, spacing_px, stacked=None, circle=None, density=None):
    """Dots of ``xy`` within ``window`` = (x0, y0, side) at ``size`` px; stacked points red."""
    from PIL import Image, ImageDraw

    x0, y0, side = window
    scale = size / side
    if density is not None:
        image = Image.new("RGB", (size, size), "white")
    else:
        image = Image.new("RGB", (size, size), "white")
    draw = ImageDraw.Draw(image)
    radius = max(1.2, 0.09 * spacing_px)
    px = (xy - [x0, y0]) * scale
    inside = (px[:, 0] > -radius) & (px[:, 0] < size + radius) & (px[:, 1] > -radius) & (px[:, 1] < size + radius)
    for i in np.nonzero(inside)[0]:
        colour = (220, 0, 0) if stacked is not None and stacked[i] else (0, 0, 0)
        cx, cy = px[i]
        draw.ellipse([cx - radius, cy - radius, cx + radius, cy + radius], fill=colour)
    if stacked is not None:
        for i in np.nonzero(inside & stacked)[0]:
            cx, cy = px[i]
            draw.ellipse([cx - 3 * radius, cy - 3 * radius, cx + 3 * radius, cy + 3 * radius], outline=(220, 0, 0), width=1)
    if circle is not None:
        (cx, cy), r = circle
        cx, cy, r = (cx - x0) * scale, (cy - y0) * scale, r * scale
        draw.ellipse([cx - r, cy - r, cx + r, cy + r], outline=(0, 90, 255), width=2)
    draw.rectangle([0, 0, size - 1, size - 1], outline=(160, 160, 160))
    return image


def contact_sheet(keep: dict, path: Path) -> Path | None:
    from PIL import Image, ImageDraw

    tiles: list[tuple[str, object]] = []
    size = 420
    for name in PRESETS:
        entry = keep.get(f"constant_{name}")
        if entry is None:
            continue
        n = len(entry["synth"])
        unit = fs.r_max(n, 1.0)
        window = (0.0, 0.0, 0.22)  # top-left corner: shows the border too
        for label in ("synth", "gen"):
            pts = entry[label]
            periodic = label == "gen"
            intensity = fs.Intensity.constant(n)
            nn = fs.nearest_neighbours(pts, (1.0, 1.0), periodic) / unit
            lec = fs.empty_circles(pts, intensity, periodic=periodic)
            circle = (lec["largest_at"], lec["largest_radius_abs"]) if lec["largest_at"] else None
            if circle and not (window[0] <= circle[0][0] <= window[0] + window[2] and window[1] <= circle[0][1] <= window[1] + window[2]):
                circle = None
            tiles.append((f"{name} {'synthesised' if label == 'synth' else 'generator'} (top-left 0.22; red = stacked)",
                          _render(pts, window, size, unit * size / window[2], nn < fs.STACKED, circle)))
    for other in ("red", "white"):
        entry = keep.get(f"edge_{other}")
        if entry is None:
            continue
        n = len(entry["synth"])
        w, h = entry["domain"]
        unit = fs.r_max(n, w * h)
        window = (0.125 - 0.1, 0.14, 0.2)  # centred on the first edge, x = 0.125 (blue left, other right)
        nn = fs.nearest_neighbours(entry["synth"], (w, h)) / unit
        tiles.append((f"blue (left) | {other} (right) edge at centre, synthesised", _render(entry["synth"], window, size, unit * size / window[2], nn < fs.STACKED)))
    for name in PHOTOS:
        entry = keep.get(f"photo_{name}")
        if entry is None:
            continue
        n = len(entry["synth"])
        window = (0.3, 0.15, 0.22) if name == "camera" else (0.35, 0.1, 0.22)
        intensity = fs.Intensity(entry["density"], entry["domain"], n)
        for label in ("synth", "lloyd", "ccvt"):
            pts = entry[label]
            local = intensity.local_r_max(pts)
            nn = fs.nearest_neighbours(pts, entry["domain"]) / local
            spacing = math.sqrt(1.0 / n) * size / window[2]
            tiles.append((f"{name} {dict(synth='synthesised', lloyd='weighted Lloyd', ccvt='CCVT')[label]} (crop 0.22)",
                          _render(pts, window, size, spacing, nn < fs.STACKED)))
    if not tiles:
        return None
    columns = 2
    rows = (len(tiles) + 1) // 2
    label_h = 18
    sheet = Image.new("RGB", (columns * (size + 10) + 10, rows * (size + label_h + 10) + 10), (235, 235, 235))
    draw = ImageDraw.Draw(sheet)
    for k, (label, tile) in enumerate(tiles):
        r, c = divmod(k, columns)
        x, y = 10 + c * (size + 10), 10 + r * (size + label_h + 10)
        draw.text((x, y), label, fill=(0, 0, 0))
        sheet.paste(tile, (x, y + label_h))
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)
    return path


# --------------------------------------------------------------------------- main


def code_identity() -> dict:
    import synthesis

    where = Path(synthesis.__file__).resolve().parent
    info = {"synthesis_path": str(where)}
    try:
        info["commit"] = subprocess.run(["git", "-C", str(where), "rev-parse", "HEAD"], capture_output=True, text=True,
                                        check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(where), "status", "--porcelain", "--", "."], capture_output=True, text=True).stdout
        info["synthesis_dirty"] = bool(dirty.strip())
    except Exception:  # noqa: BLE001 - not a git checkout
        info["commit"] = None
    return info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="1 seed, edges blue|red only, camera only")
    parser.add_argument("--only", action="append", choices=CASES, help="run only this case (repeatable)")
    parser.add_argument("--seeds", type=int, default=None, help="number of seeds (default 3; 1 with --quick)")
    parser.add_argument("--out", type=Path, default=None, help="results JSON (default out/bench/fidelity.json, "
                                                                "fidelity_quick.json for --quick/--only)")
    parser.add_argument("--sheet", type=Path, default=RESULTS_DIR / "fidelity_sheet.png", help="contact sheet PNG")
    parser.add_argument("--photos", action="append", choices=PHOTOS, help="photos case: only this picture (repeatable)")
    parser.add_argument("--photo-n", type=int, default=N_PHOTO, help=f"photos case: points (default {N_PHOTO})")
    parser.add_argument("--photo-seeds", type=int, default=None, help="photos case: number of seeds (default: --seeds)")
    parser.add_argument("--strip-presets", action="append", choices=STRIP_PRESETS, help="strips case: only this preset (repeatable)")
    parser.add_argument("--density-edges", action="append", choices=list(DENSITY_EDGES),
                        help="strips case: only this density edge (repeatable; default: all unless --strip-presets)")
    parser.add_argument("--label", default=None, help="a name for the code measured (recorded in the results)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    seeds = list(range(args.seeds if args.seeds else (1 if args.quick else 3)))
    cases = args.only or CASES
    out_path = args.out or RESULTS_DIR / ("fidelity_quick.json" if (args.quick or args.only) else "fidelity.json")
    results: dict = {"meta": {"label": args.label, "seeds": seeds, "quick": args.quick, "cases": cases,
                              "torch_threads": args.threads, "code": code_identity(),
                              "machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                                          "load_average_1min_start": round(os.getloadavg()[0], 2)},
                              "definitions": DEFINITIONS}}
    keep: dict = {}
    start_all = time.perf_counter()
    for case in cases:
        start = time.perf_counter()
        if case == "constant":
            results[case] = case_constant(seeds, keep)
        elif case == "edges":
            results[case] = case_edges(seeds, ["red"] if args.quick else ["red", "white"], keep)
        elif case == "strips":
            results[case] = case_strips(seeds, args.strip_presets or STRIP_PRESETS)
            names = args.density_edges or ([] if args.strip_presets else list(DENSITY_EDGES))
            if names:
                results[case]["density_edges"] = case_density_edges(seeds, names)
        elif case == "logo":
            results[case] = case_logo(seeds)
        elif case == "photos":
            results[case] = case_photos(seeds if args.photo_seeds is None else list(range(args.photo_seeds)),
                                        args.photos or (["camera"] if args.quick else PHOTOS), keep, args.photo_n)
        results[case]["bench_seconds"] = round(time.perf_counter() - start, 1)
        print(f"== {case}: {results[case]['bench_seconds']} s", flush=True)
    results["targets"] = target_rows(results)
    results["meta"]["machine"]["load_average_1min_end"] = round(os.getloadavg()[0], 2)
    results["meta"]["bench_seconds"] = round(time.perf_counter() - start_all, 1)
    sheet = contact_sheet(keep, args.sheet)
    results["meta"]["contact_sheet"] = str(sheet) if sheet else None
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(results, indent=1, default=_jsonable) + "\n")
    print_table(results["targets"])
    print(f"results: {out_path}" + (f"; contact sheet: {sheet}" if sheet else ""))


def _jsonable(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(type(value))


DEFINITIONS = {
    "r_max": "2 sqrt(A / (2 sqrt(3) n)); local r_max = 2 / sqrt(2 sqrt(3) lambda(x)), lambda(x) = n density(x) / (mean density A), "
             "density = 1 - L/100 at the pixel containing x",
    "fine_pcf": "translation edge correction (Ohser; torus: minimum image), Gaussian kernel sigma 0.05 r_max, annulus normalisation "
                "(finite, unbiased from r = 0), r = 0..2.5 r_max in 101 steps",
    "pcf_ratio": "RMS over r of (g_synth - g_gen_A) / RMS of (g_gen_A - g_gen_B); generators on the torus, synthesis on the bounded map",
    "stacked_fraction": "share of points whose NN distance < 0.05 local r_max (generator: mean of its two realisations per seed)",
    "min_nn": "smallest NN distance in local r_max",
    "nn_cv": "std/mean of NN distances (local r_max), points whose NN is shorter than their distance to the border (minus sampling); "
             "generator: mean of its two realisations per seed",
    "largest_empty_circle": "Delaunay circumcircle, equivalent radius sqrt(E sqrt(3)/(2 pi)) with E the expected count in the disk "
                            "(= R / r_max at constant density); only circles inside the domain whose disk has density >= 0.15 "
                            "everywhere; holes_over_1 = distinct circles with equivalent radius > 1",
    "edge_strips": "counts in strips 0.5 r_max wide against the signed distance to the nearest stripe edge / expected, "
                   "min and max over strips within 3 r_max",
    "border_strips": "counts in rings 0.5 r_max wide at distance 0-3 r_max from the border / expected (n ring area / A)",
    "density_psnr": "point counts per pixel and target density, both mean 1, blurred by a Gaussian of 1, 2 or 4 mean spacings sqrt(A/n) "
                    "(zero padding outside the domain); 10 log10(max(target)^2 / MSE)",
    "objective_validity": "synthesiser's own final_loss of a generator realisation / of the synthesised output (same map, same n)",
}


if __name__ == "__main__":
    main()
