"""Out-of-distribution evaluation of a points-to-map model: the figures of its targets.

Every input is made here, by other methods than the synthesiser the model was
trained on, at the synthesiser's scale (50,000 points per fully dark unit
square unless said otherwise), and read the way ``patternshop infer`` reads it
(:func:`export.runtime.infer_map`: automatic scale, ink calibrated to the points,
L smoothed within the model's predicted uncertainty when it has an ``l_scale``
output; ``--raw``: the network's output as it came).

1. **Stipplings of pictures**: scikit-image's ``camera``, ``astronaut``,
   ``moon`` and ``coins`` only (the other pictures stay unseen checks), density
   ``1 - L*/100`` of the picture, stippled with :data:`STIPPLE_POINTS` points by
   density-proportional random sampling, a weighted Lloyd stippler and
   Floyd-Steinberg dithering (:mod:`data_gen.stipplers`). The pattern is read at
   its true points per ink; inferred L against the picture's L at the map's
   size: SSIM (data range 100) and MAE (L units), beside a Gaussian KDE of the
   points at its best bandwidth of :data:`patternshop_nn.baselines.KDE_BANDWIDTHS`
   for each measure (an oracle), and the mean inferred L where the picture is
   full ink (L <= 5).
2. **Stationary processes** at densities :data:`DENSITIES` (the unit square,
   ``n = 50,000 d``; 1.5 only readable through the automatic scale): Poisson,
   scipy's Poisson-disk, Lloyd (CVT of a constant density), jittered grid and
   Thomas clusters, each with its preset (:data:`STATIONARY`); share of the
   map's pixels whose nearest preset colour is the right one; mean L, a, b and
   the L spread.
3. **Lattice**: on the same stationary inputs, the share of the network output's
   L variance and a, b variance (at the raster's resolution, over the domain
   less 64 px at its border) that is the mean over each phase modulo 64 and
   32 px; a map without lattice has ``p^2 / pixels`` by chance (given beside).
4. **Inventing nothing**: an empty pattern (min L, share of pixels at L >= 97);
   one point at (0.5, 0.5) (share of pixels at L >= 95, and the points
   ``synthesize`` would make of the map); Poisson points at density 0.5 in the
   left half only (the share of the map's ink in the empty right half, and, unless
   quick, of the points synthesised from it).
5. **Point count**: ``synthesize``'s count of the inferred map (``points_per_ink x
   mean density`` at the scale infer chose) over the input count, for Poisson
   patterns of :data:`COUNTS` points.
6. **Cost**: ONNX Runtime milliseconds per 256 x 256 raster on one thread
   (median of 10), and the model file's size.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image

from data_gen.stipplers import METHODS, lloyd_stipple, poisson_disk
from export.evidence import ScaleChoice
from export.runtime import Inference, OnnxModel, infer_map
from patternshop_nn.baselines import KDE_BANDWIDTHS, count_raster, kde_density
from synthesis.conventions import POINTS_PER_INK, full_ink_points
from synthesis.labmap import LabMap
from synthesis.palette import Palette
from synthesis.points import PointSet

PICTURES = ("camera", "astronaut", "moon", "coins")  # no other scikit-image picture: the rest are unseen checks
STIPPLERS = ("random", "lloyd", "floyd_steinberg")
STIPPLE_POINTS = 25_000
DENSITIES = (0.05, 0.2, 0.5, 1.0, 1.5)
COUNTS = (200, 1_000, 5_000, 20_000, 50_000)
PHASES = (64, 32)  # raster pixels: 2**levels of the U-Net and half of it
LATTICE_MARGIN_PX = 64  # raster pixels left out at the domain's border when measuring the lattice
FULL_INK_L = 5.0  # picture pixels at most this light count as full ink
QUICK = {"pictures": ("camera",), "densities": (0.2, 1.5), "counts": (200, 5_000, 50_000)}


def _lloyd_process(n: int, seed: int) -> np.ndarray:
    """Lloyd's CVT of a constant density on the unit square (30 iterations, about 8 grid pixels per point)."""
    side = math.ceil(math.sqrt(8 * n))
    return lloyd_stipple(np.ones((side, side)), n, (1.0, 1.0), iterations=30, seed=seed)


def _generator(name: str) -> Callable[[int, int], np.ndarray]:
    from synthesis.generators import generate

    return lambda n, seed: generate(name, n, seed)


STATIONARY: dict[str, tuple[Callable[[int, int], np.ndarray], str]] = {  # process -> (points(n, seed), preset)
    "poisson": (_generator("white"), "white"),
    "poisson_disk": (poisson_disk, "blue"),
    "lloyd": (_lloyd_process, "blue"),
    "jitter": (_generator("jitter"), "step"),  # the jittered grid: its preset is merged into step (palette.MERGED_PRESETS)
    "thomas": (_generator("red"), "red"),
}


def infer(points: PointSet, model: OnnxModel, raw: bool, scale: ScaleChoice | None = None) -> Inference:
    """``infer``'s reading of a pattern, or with ``raw`` the network's alone: one run, no calibration or smoothing."""
    return infer_map(points, model, scale=scale, calibrate=not raw, symmetries=1 if raw else None)


def picture_density(name: str) -> tuple[np.ndarray, tuple[float, float]]:
    """(density (H, W) in [0, 1] = 1 - L*/100 of a scikit-image picture, its domain (long side 1))."""
    import skimage.data

    if name not in PICTURES:
        raise ValueError(f"{name!r} is not one of the evaluation pictures {PICTURES}")
    image = getattr(skimage.data, name)().astype(np.float64) / 255.0
    rgb = np.repeat(image[..., None], 3, axis=-1) if image.ndim == 2 else image[..., :3]
    density = np.clip(1.0 - LabMap.from_srgb(rgb).L / 100.0, 0.0, 1.0)
    height, width = density.shape
    return density, (width / max(height, width), height / max(height, width))


def resample(density: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``density`` (H, W) in [0, 1] area-resampled to ``shape`` (H', W')."""
    image = Image.fromarray(np.asarray(density, np.float32))
    return np.asarray(image.resize((shape[1], shape[0]), Image.Resampling.BOX), np.float64)


def points_per_ink_of(n: int, density: np.ndarray) -> float:
    """The true scale of n points drawn from ``density`` (H, W) on its domain (longer side 1): points per unit
    area of full ink (the synthesiser's ``n = points_per_ink x w x h x mean density``)."""
    height, width = density.shape
    return n / full_ink_points(float(np.mean(density)), (width / max(height, width), height / max(height, width)))


def l_scores(truth_L: np.ndarray, L: np.ndarray) -> tuple[float, float]:
    """(SSIM with data range 100, mean |error|) of an L channel against the truth, both (H, W) in [0, 100]."""
    from skimage.metrics import structural_similarity

    return float(structural_similarity(truth_L, L, data_range=100.0)), float(np.mean(np.abs(truth_L - L)))


def kde_L(xy: np.ndarray, shape: tuple[int, int], points_per_ink: float, bandwidth_px: float) -> np.ndarray:
    """(H, W) L of a Gaussian KDE of points on a map of ``shape`` read at ``points_per_ink`` (the synthesiser's)."""
    return 100.0 * (1.0 - kde_density(count_raster(np.asarray(xy) * max(shape), shape), points_per_ink, bandwidth_px))


def kde_scores(xy: np.ndarray, truth_L: np.ndarray, points_per_ink: float) -> dict:
    """Best SSIM and best MAE of the KDE's L over :data:`KDE_BANDWIDTHS` (map pixels), each with its bandwidth."""
    scores = {h: l_scores(truth_L, kde_L(xy, truth_L.shape, points_per_ink, h)) for h in KDE_BANDWIDTHS}
    best_ssim = max(scores, key=lambda h: scores[h][0])
    best_mae = min(scores, key=lambda h: scores[h][1])
    return {"kde_ssim": round(scores[best_ssim][0], 4), "kde_ssim_bandwidth_px": best_ssim,
            "kde_mae": round(scores[best_mae][1], 3), "kde_mae_bandwidth_px": best_mae}


def stipplings(model: OnnxModel, pictures: tuple[str, ...], seed: int, raw: bool, previews: list) -> list[dict]:
    """Section 1 of the module docstring; appends (label, [truth, points, inferred, KDE]) rows to ``previews``."""
    rows = []
    for picture in pictures:
        density, domain = picture_density(picture)
        for method in STIPPLERS:
            xy = METHODS[method](density, STIPPLE_POINTS, domain, np.random.default_rng(seed))
            scale = points_per_ink_of(len(xy), density)
            lab_map = infer(PointSet(xy, domain), model, raw, scale=ScaleChoice(scale, False)).lab_map
            truth = resample(density, lab_map.L.shape)
            truth_L = 100.0 * (1.0 - truth)
            ssim, mae = l_scores(truth_L, lab_map.L.astype(np.float64))
            kde = kde_scores(xy, truth_L, scale)
            full = truth_L <= FULL_INK_L
            row = {"picture": picture, "method": method, "n": len(xy), "points_per_ink": round(scale),
                   "ssim": round(ssim, 4), "mae": round(mae, 3), **kde,
                   "better_than_kde": bool(ssim > kde["kde_ssim"] and mae < kde["kde_mae"]),
                   "full_ink_pixels": int(full.sum()),
                   "full_ink_mean_L": round(float(lab_map.L[full].mean()), 2) if full.sum() >= 50 else None}
            rows.append(row)
            previews.append((f"{picture} {method}", [grey(truth_L), points_image(xy, truth_L.shape), lab_map.to_srgb(),
                                                     grey(kde_L(xy, truth_L.shape, scale, kde["kde_mae_bandwidth_px"]))]))
    return rows


def phase_locked_share(channels: np.ndarray, period: int) -> float:
    """Share of the variance of channels (C, H, W), summed over C, in their mean over each phase modulo ``period``."""
    c, height, width = channels.shape
    h, w = height // period * period, width // period * period
    x = np.asarray(channels[:, :h, :w], np.float64)
    centred = x - x.mean(axis=(1, 2), keepdims=True)
    phase_means = centred.reshape(c, h // period, period, w // period, period).mean(axis=(1, 3))
    total = float((centred**2).mean(axis=(1, 2)).sum())
    return float((phase_means**2).mean(axis=(1, 2)).sum() / total) if total > 0 else 0.0


def lattice(inference: Inference) -> dict:
    """Phase-locked shares of L and a, b variance in the network's output over the domain (section 3),
    :data:`LATTICE_MARGIN_PX` in from its border where it is large enough (border effects are not a lattice)."""
    crop = inference.output
    if min(crop.shape[1:]) >= 4 * LATTICE_MARGIN_PX:
        crop = crop[:, LATTICE_MARGIN_PX:-LATTICE_MARGIN_PX, LATTICE_MARGIN_PX:-LATTICE_MARGIN_PX]
    result = {}
    for period in PHASES:
        result[f"L_locked_{period}"] = round(phase_locked_share(crop[:1], period), 4)
        result[f"ab_locked_{period}"] = round(phase_locked_share(crop[1:], period), 4)
        result[f"chance_{period}"] = round(period * period / (crop.shape[1] * crop.shape[2]), 4)
    return result


def nearest_preset_share(lab_map: LabMap, palette: Palette, preset: str) -> float:
    """Share of the map's pixels whose a, b is nearest (Euclidean) to ``preset`` among the palette's presets."""
    names, colours = zip(*palette.preset_ab().items(), strict=True)
    distances = np.linalg.norm(lab_map.ab.reshape(-1, 1, 2) - np.array(colours)[None], axis=-1)
    return float(np.mean(np.array(names)[distances.argmin(axis=1)] == preset))


def stationary(model: OnnxModel, palette: Palette, densities: tuple[float, ...], seed: int, raw: bool,
               previews: list) -> list[dict]:
    """Sections 2 and 3: one row per process and density."""
    rows = []
    for process, (make, preset) in STATIONARY.items():
        maps = []
        for density in densities:
            n = round(density * POINTS_PER_INK)
            xy = make(n, seed)
            inference = infer(PointSet(xy), model, raw)
            lab_map = inference.lab_map
            rows.append({"process": process, "preset": preset, "density": density, "n": len(xy),
                         "points_per_ink": round(inference.scale.points_per_ink), "automatic_scale": inference.scale.points_per_ink != POINTS_PER_INK,
                         "right_preset_share": round(nearest_preset_share(lab_map, palette, preset), 4),
                         "mean_L": round(float(lab_map.L.mean()), 2), "L_spread_p5_p95": round(float(np.subtract(*np.percentile(lab_map.L, [95, 5]))), 2),
                         "mean_a": round(float(lab_map.ab[..., 0].mean()), 1), "mean_b": round(float(lab_map.ab[..., 1].mean()), 1),
                         **lattice(inference)})
            maps.append(lab_map.to_srgb())
        previews.append((process, maps))
    return rows


def synthesised_count(lab_map: LabMap, points_per_ink: float) -> int:
    """Points ``synthesize`` makes of a map at ``points_per_ink`` (0 for a white map, which it refuses)."""
    from synthesis.errors import PatternshopError
    from synthesis.synthesize import point_count

    try:
        return point_count(lab_map, points_per_ink)
    except PatternshopError:
        return 0


def inventions(model: OnnxModel, palette: Palette, seed: int, synthesise: bool, raw: bool, previews: list) -> dict:
    """Section 4: empty, one point, half-empty."""
    from synthesis.synthesize import point_count

    empty = infer(PointSet(np.zeros((0, 2))), model, raw).lab_map
    one = infer(PointSet(np.array([[0.5, 0.5]])), model, raw).lab_map
    rng = np.random.default_rng(seed)
    half_n = round(0.5 * 0.5 * POINTS_PER_INK)
    half_xy = rng.random((half_n, 2)) * [0.5, 1.0]
    half = infer(PointSet(half_xy), model, raw).lab_map
    density = half.density()
    result = {"empty_min_L": round(float(empty.L.min()), 2), "empty_share_L97": round(float(np.mean(empty.L >= 97)), 4),
              "one_point_share_L95": round(float(np.mean(one.L >= 95)), 4),
              "one_point_synthesised": synthesised_count(one, POINTS_PER_INK),
              "half_empty_n": half_n, "half_empty_ink_share_right": round(float(density[:, half.width // 2 :].sum() / density.sum()), 4)}
    if synthesise:
        from synthesis.synthesize import synthesize

        points = synthesize(half, n=point_count(half, POINTS_PER_INK), palette=palette, seed=seed).points.xy
        result["half_empty_synthesised"] = len(points)
        result["half_empty_points_share_right"] = round(float(np.mean(points[:, 0] > 0.5)), 4)
    previews.append(("empty | one point | half-empty", [empty.to_srgb(), one.to_srgb(), half.to_srgb(),
                                                        points_image(half_xy, half.L.shape)]))
    return result


def point_counts(model: OnnxModel, counts: tuple[int, ...], seed: int, raw: bool) -> list[dict]:
    """Section 5: Poisson patterns of each count -> (count synthesize would make) / count (L only: a, b do not matter)."""
    rows = []
    for n in counts:
        inference = infer(PointSet(np.random.default_rng([seed, n]).random((n, 2))), model, raw)
        made = synthesised_count(inference.lab_map, inference.scale.points_per_ink)
        rows.append({"n": n, "points_per_ink": round(inference.scale.points_per_ink), "synthesised": made, "ratio": round(made / n, 4)})
    return rows


def cost(model_path: Path) -> dict:
    """Section 6."""
    model = OnnxModel(model_path, threads=1)
    raster = np.random.default_rng(0).random((1, 1, 256, 256), dtype=np.float32) * 0.2
    model.predict(raster)
    times = []
    for _ in range(10):
        start = time.perf_counter()
        model.predict(raster)
        times.append(time.perf_counter() - start)
    return {"onnx_ms_256_one_thread": round(1000 * float(np.median(times)), 2), "model_mb": round(model_path.stat().st_size / 1e6, 2)}


def grey(L: np.ndarray) -> np.ndarray:
    """(H, W, 3) sRGB-ish grey preview of an L channel in [0, 100]."""
    return np.repeat(np.clip(np.asarray(L) / 100.0, 0, 1)[..., None], 3, axis=-1)


def points_image(xy: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) preview of points: each pixel darkened by its count (4 points: black)."""
    counts = count_raster(np.asarray(xy) * max(shape), shape)
    return grey(100.0 * (1.0 - np.clip(counts / 4.0, 0.0, 1.0)))


def contact_sheet(rows: list[tuple[str, list[np.ndarray]]], path: Path, tile: int = 192) -> None:
    """A PNG with one row of tiles per entry (each image fitted into ``tile`` px, white around), labels on the left."""
    from PIL import ImageDraw

    from synthesis.atomic import atomic_path

    columns = max(len(images) for _, images in rows)
    label_width = 150
    sheet = Image.new("RGB", (label_width + columns * (tile + 4), len(rows) * (tile + 4)), "white")
    draw = ImageDraw.Draw(sheet)
    for r, (label, images) in enumerate(rows):
        draw.text((4, r * (tile + 4) + tile // 2), label, fill="black")
        for c, image in enumerate(images):
            picture = Image.fromarray((np.clip(image, 0, 1) * 255).round().astype(np.uint8))
            picture.thumbnail((tile, tile), Image.Resampling.BOX if picture.width > tile else Image.Resampling.NEAREST)
            sheet.paste(picture, (label_width + c * (tile + 4), r * (tile + 4)))
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        sheet.save(tmp, format="PNG")


def evaluate_ood(model_path: Path, palette: Palette, quick: bool, seed: int, preview_dir: Path | None, raw: bool = False) -> dict:
    """All sections (reduced with ``quick``: :data:`QUICK`); contact sheets into ``preview_dir`` when given.

    ``raw``: the network's maps as they came (one run, no calibration or smoothing) instead of ``infer``'s.
    """
    model = OnnxModel(model_path, threads=1)
    pictures = QUICK["pictures"] if quick else PICTURES
    densities = QUICK["densities"] if quick else DENSITIES
    counts = QUICK["counts"] if quick else COUNTS
    sheets: dict[str, list] = {"stipplings": [], "stationary": [], "inventions": []}
    start = time.perf_counter()
    results = {"model": str(model_path), "model_name": model.metadata.get("name"), "quick": quick, "seed": seed, "raw": raw,
               "l_scale": model.has_l_scale,
               "stipplings": stipplings(model, pictures, seed, raw, sheets["stipplings"]),
               "stationary": stationary(model, palette, densities, seed, raw, sheets["stationary"]),
               "inventions": inventions(model, palette, seed, not quick, raw, sheets["inventions"]),
               "point_counts": point_counts(model, counts, seed, raw), "cost": cost(model_path)}
    results["seconds"] = round(time.perf_counter() - start, 1)
    results["targets"] = targets(results)
    if preview_dir is not None:
        for name, rows in sheets.items():
            contact_sheet(rows, preview_dir / f"ood_{name}.png")
    return results


def targets(results: dict) -> list[dict]:
    """The network's targets: (figure, target, measured, met)."""
    stip, stat, inv = results["stipplings"], results["stationary"], results["inventions"]
    locked = max(max(row[f"L_locked_{p}"], row[f"ab_locked_{p}"]) for row in stat for p in PHASES)
    ratios = [row["ratio"] for row in results["point_counts"]]
    rows = [("empty raster: min L", ">= 97", inv["empty_min_L"], inv["empty_min_L"] >= 97),
            ("one point: pixels at L >= 95", ">= 99 %", f"{100 * inv['one_point_share_L95']:.1f} %", inv["one_point_share_L95"] >= 0.99)]
    if "half_empty_points_share_right" in inv:
        share = inv["half_empty_points_share_right"]
        rows.append(("half-empty: resynthesised points in the empty half", "< 0.5 %", f"{100 * share:.2f} %", share < 0.005))
    else:
        share = inv["half_empty_ink_share_right"]
        rows.append(("half-empty: ink in the empty half (quick: no synthesis)", "< 0.5 %", f"{100 * share:.2f} %", share < 0.005))
    rows += [("L and a,b variance locked to a 64/32-px phase (max)", "<= 5 %", f"{100 * locked:.1f} %", locked <= 0.05),
             ("stipplings better than the best KDE in SSIM and MAE", "every case",
              f"{sum(r['better_than_kde'] for r in stip)} of {len(stip)}", all(r["better_than_kde"] for r in stip)),
             ("stationary: nearest preset right (min over cases)", ">= 90 %",
              f"{100 * min(r['right_preset_share'] for r in stat):.1f} %", min(r["right_preset_share"] for r in stat) >= 0.9),
             ("infer -> synthesize point count ratio", "within 5 %", f"{min(ratios):.3f}-{max(ratios):.3f}",
              all(0.95 <= r <= 1.05 for r in ratios)),
             ("ONNX ms per 256^2, one thread", "<= 25", results["cost"]["onnx_ms_256_one_thread"], results["cost"]["onnx_ms_256_one_thread"] <= 25),
             ("model size MB", "<= 30", results["cost"]["model_mb"], results["cost"]["model_mb"] <= 30)]
    return [{"figure": f, "target": t, "measured": m, "met": bool(ok)} for f, t, m, ok in rows]


def markdown(results: dict) -> str:
    """The results as markdown tables: targets, stipplings, stationary processes, point counts."""
    if results["raw"]:
        reading = "as the network gave them (--raw)"
    elif results["l_scale"]:
        reading = "as infer makes them (symmetries averaged, ink calibrated, L smoothed within the predicted uncertainty)"
    else:
        reading = "as infer makes them (symmetries averaged, ink calibrated; no l_scale output, so L not smoothed)"
    lines = [f"# Out-of-distribution evaluation: {results.get('model_name') or results['model']}", "",
             f"{'Quick' if results['quick'] else 'Full'} run, seed {results['seed']}, {results['seconds']} s, maps {reading}.", "",
             "| figure | target | measured | met |", "|---|---|---|---|"]
    lines += [f"| {t['figure']} | {t['target']} | {t['measured']} | {'yes' if t['met'] else 'no'} |" for t in results["targets"]]
    lines += ["", "## Stipplings (L against the picture)", "",
              "| picture | method | n | SSIM model | SSIM KDE (px) | MAE model | MAE KDE (px) | L at full ink |", "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['picture']} | {r['method']} | {r['n']} | {r['ssim']:.3f} | {r['kde_ssim']:.3f} ({r['kde_ssim_bandwidth_px']:g}) "
              f"| {r['mae']:.2f} | {r['kde_mae']:.2f} ({r['kde_mae_bandwidth_px']:g}) | {r['full_ink_mean_L'] if r['full_ink_mean_L'] is not None else '-'} |"
              for r in results["stipplings"]]
    lines += ["", "## Stationary processes", "",
              "| process | density | points per ink | right preset | mean L | L p95-p5 | mean a, b | L locked 64/32 | a,b locked 64/32 | chance 64 |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['process']} ({r['preset']}) | {r['density']:g} | {r['points_per_ink']}{' (auto)' if r['automatic_scale'] else ''} "
              f"| {100 * r['right_preset_share']:.1f} % | {r['mean_L']:.1f} | {r['L_spread_p5_p95']:.1f} | {r['mean_a']:.0f}, {r['mean_b']:.0f} "
              f"| {100 * r['L_locked_64']:.1f} / {100 * r['L_locked_32']:.1f} % | {100 * r['ab_locked_64']:.1f} / {100 * r['ab_locked_32']:.1f} % "
              f"| {100 * r['chance_64']:.2f} % |" for r in results["stationary"]]
    lines += ["", "## Inventions", "", *[f"- {key}: {value}" for key, value in results["inventions"].items()],
              "", "## infer -> synthesize point count", "", "| n | points per ink | synthesised | ratio |", "|---|---|---|---|"]
    lines += [f"| {r['n']} | {r['points_per_ink']} | {r['synthesised']} | {r['ratio']:.3f} |" for r in results["point_counts"]]
    return "\n".join(lines) + "\n"
