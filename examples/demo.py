"""The Patternshop loop on the bundled example: points -> map -> edit -> points.

1. **Read** a point pattern (default ``examples/logo_points.txt``: about 7,200
   points synthesised from ``examples/logo.tif`` by ``examples/make_examples.py``).
2. **Infer** its map with the network (ONNX Runtime, :func:`export.runtime.points_to_map`),
   reading the pattern at ``--points-per-ink`` points per unit area of full ink.
3. **Edit** the map as in the paper's Fig. 1 (:mod:`synthesis.edits`): the background
   (where the inferred density is below ``--background-below``) gets another
   preset correlation (``--preset``, default step noise) and a density
   gradient from top to bottom (``--gradient``).
4. **Synthesise** points from the edited map (:func:`synthesis.synthesize.synthesize`,
   fast schedule, ``n = points_per_ink x area x mean density``, so the count stays comparable).

Writes into ``--out`` (default ``out/demo``): ``input_points.png``,
``inferred.tif`` + ``inferred.png`` (sRGB preview), ``edited.tif`` + ``edited.png``,
``output_points.txt`` / ``.png`` / ``.svg``, ``contact_sheet.png`` (input points |
inferred map | edited map | output points) and ``summary.json`` (timings per
stage, point counts); prints the summary. Every file is written atomically.

Usage: ``python examples/demo.py [--out DIR] [--model FILE] [--iterations K] ...``
(``make demo`` runs it). Errors are one line on stderr with exit status 2;
``--debug`` shows tracebacks.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from PIL import Image, ImageDraw, ImageFont
from scipy.ndimage import gaussian_filter

from synthesis.edits import density_gradient, set_correlation
from export.runtime import DEFAULT_MODEL, OnnxModel, check_palette, pattern_raster, points_to_map
from patternshop.cli import OneLineErrorParser
from synthesis.atomic import atomic_path, atomic_write_text
from synthesis.conventions import POINTS_PER_INK_MEANING
from synthesis.errors import PatternshopError, PatternshopWarning
from synthesis.labmap import LabMap
from synthesis.mapio import write_map, write_preview
from synthesis.palette import load_palette
from synthesis.points import PointSet, read_points, write_points
from synthesis.render import dots_grey, render_png, write_svg
from synthesis.synthesize import point_count, synthesize
from synthesis.tone import density_fidelity

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_POINTS = ROOT / "examples" / "logo_points.txt"
PROG = "demo"
GAP = 8  # pixels around and between the contact sheet's panels
LABEL_HEIGHT = 18  # pixels under each panel for its label
BACKGROUND_SMOOTHING = 2.0  # pixels of Gaussian smoothing of the density before thresholding it, and of the region's edge
OUTPUTS = ("input_points.png", "inferred.tif", "inferred.png", "edited.tif", "edited.png", "output_points.txt",
           "output_points.png", "output_points.svg", "contact_sheet.png", "summary.json")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(
        prog=PROG, description=__doc__.split("\n\n")[0],
        epilog="Example (a fast smoke run): python examples/demo.py --out /tmp/demo --iterations 20 --size 256")
    parser.add_argument("--points", default=str(DEFAULT_POINTS), metavar="FILE",
                        help="input point file (default examples/logo_points.txt)")
    parser.add_argument("--model", metavar="FILE", help=f"ONNX model (default the shipped {DEFAULT_MODEL.relative_to(ROOT)})")
    parser.add_argument("--out", default="out/demo", metavar="DIR", help="output folder (default out/demo; created if missing)")
    parser.add_argument("--points-per-ink", type=float, default=30_000, metavar="K",
                        help=f"{POINTS_PER_INK_MEANING}: the scale the input is read at and the output "
                        "synthesised at (default 30000, the bundled points' scale)")
    parser.add_argument("--iterations", type=int, metavar="K", help="synthesis iterations (default: the fast schedule's 250)")
    parser.add_argument("--size", type=int, default=384, metavar="PX", help="width of each contact-sheet panel (default 384)")
    parser.add_argument("--png-width", type=int, default=1024, metavar="PX", help="width of the point renderings (default 1024)")
    parser.add_argument("--preset", default="step", help="correlation preset of the edited background (default step)")
    parser.add_argument("--background-below", type=float, default=0.33, metavar="D",
                        help="the background is where the inferred density is below D (default 0.33)")
    parser.add_argument("--gradient", nargs=2, type=float, default=(0.05, 0.35), metavar=("TOP", "BOTTOM"),
                        help="background density at the top and at the bottom of the map (default 0.05 0.35)")
    parser.add_argument("--threads", type=int, default=1, metavar="N",
                        help="torch threads for the synthesis and ONNX Runtime threads (default 1; 2 may be faster "
                        "on an idle machine)")
    parser.add_argument("--seed", type=int, default=0, help="synthesis seed (default 0)")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    return parser


def check_args(args: argparse.Namespace) -> Path:
    """The model file to use; one-line errors for bad settings."""
    if args.points_per_ink <= 0 or args.size < 8 or args.png_width < 8 or args.threads < 1:
        raise PatternshopError("--points-per-ink must be > 0, --size and --png-width >= 8 px, --threads >= 1")
    if args.iterations is not None and args.iterations < 0:
        raise PatternshopError(f"--iterations must be >= 0, got {args.iterations}")
    if not all(0.0 <= d <= 1.0 for d in (*args.gradient, args.background_below)):
        raise PatternshopError("--gradient densities and --background-below must lie in [0, 1]")
    model = Path(args.model) if args.model else DEFAULT_MODEL
    if not model.is_file():
        raise PatternshopError(f"no model at {model}: train one with 'python train.py', export it with 'patternshop export "
                               f"runs/procedural/checkpoints/best.ckpt {DEFAULT_MODEL.relative_to(ROOT)}', or pass --model FILE")
    return model


def background_region(lab_map: LabMap, below: float) -> np.ndarray:
    """(H, W) float32 weights: 1 where the (slightly smoothed) density is below ``below``, soft at the edge."""
    density = gaussian_filter(lab_map.density().astype(np.float64), BACKGROUND_SMOOTHING, mode="nearest")
    region = gaussian_filter((density < below).astype(np.float64), BACKGROUND_SMOOTHING / 2, mode="nearest")
    return region.astype(np.float32)


def edit_map(lab_map: LabMap, ab: tuple[float, float], below: float, gradient: tuple[float, float]) -> tuple[LabMap, np.ndarray]:
    """Fig. 1 of the paper: the background gets correlation ``ab`` and a top-to-bottom density gradient."""
    region = background_region(lab_map, below)
    edited = set_correlation(lab_map, ab, region)
    w, h = lab_map.domain
    edited = density_gradient(edited, (w / 2, 0.0), (w / 2, h), gradient, "set", region)
    return edited, region


def map_panel(lab_map: LabMap, width: int, height: int) -> Image.Image:
    return Image.fromarray(lab_map.to_srgb8()).resize((width, height), Image.Resampling.BILINEAR)


def points_panel(points: PointSet, width: int) -> Image.Image:
    return Image.fromarray(dots_grey(points, width)).convert("RGB")


def sheet_size(size: int, domain: tuple[float, float]) -> tuple[int, int]:
    """(width, height) of the contact sheet with panels ``size`` px wide for a domain (w, h)."""
    panel_height = max(1, round(size * domain[1] / domain[0]))
    return 4 * size + 5 * GAP, panel_height + LABEL_HEIGHT + 2 * GAP


def contact_sheet(panels: list[tuple[Image.Image, str]], size: int, domain: tuple[float, float]) -> Image.Image:
    """The four panels side by side, each ``size`` px wide, labelled underneath."""
    width, height = sheet_size(size, domain)
    sheet = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default(size=12)
    for slot, (panel, label) in enumerate(panels):
        x = GAP + slot * (size + GAP)
        sheet.paste(panel, (x, GAP))
        draw.rectangle([x - 1, GAP - 1, x + panel.width, GAP + panel.height], outline=(170, 170, 170))
        draw.text((x, GAP + panel.height + 3), label, fill=(0, 0, 0), font=font)
    return sheet


def run(args: argparse.Namespace, model_path: Path) -> dict:
    """The loop; returns the summary (also written as summary.json)."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seconds: dict[str, float] = {}
    started = time.perf_counter()

    clock = time.perf_counter()
    points = read_points(args.points)
    seconds["read"] = time.perf_counter() - clock

    clock = time.perf_counter()
    model = OnnxModel(model_path, threads=args.threads)
    check_palette(model)
    inferred = points_to_map(points, model, points_per_ink=args.points_per_ink)
    seconds["infer"] = time.perf_counter() - clock
    raster_side = pattern_raster(points, model.raster_size, model.points_per_ink, args.points_per_ink)[0].shape[0]

    clock = time.perf_counter()
    palette = load_palette()
    presets = palette.preset_ab()
    if args.preset not in presets:
        raise PatternshopError(f"unknown preset {args.preset!r}; presets: {', '.join(presets)}")
    edited, region = edit_map(inferred, presets[args.preset], args.background_below, tuple(args.gradient))
    seconds["edit"] = time.perf_counter() - clock

    clock = time.perf_counter()
    n = point_count(edited, args.points_per_ink)
    result = synthesize(edited, n=n, palette=palette, schedule="fast", iterations=args.iterations, seed=args.seed)
    output = result.points
    seconds["synthesize"] = time.perf_counter() - clock

    clock = time.perf_counter()
    render_png(points, out / "input_points.png", width_px=args.png_width)
    for name, lab_map in (("inferred", inferred), ("edited", edited)):
        write_map(lab_map, out / f"{name}.tif", bits=16)
        write_preview(lab_map, out / f"{name}.png", scale=2)
    write_points(output, out / "output_points.txt")
    render_png(output, out / "output_points.png", width_px=args.png_width)
    write_svg(output, out / "output_points.svg")
    width, height = args.size, max(1, round(args.size * points.domain[1] / points.domain[0]))
    sheet = contact_sheet([(points_panel(points, width), f"input points (n = {len(points)})"),
                           (map_panel(inferred, width, height), "inferred map"),
                           (map_panel(edited, width, height), f"edited: {args.preset} background + gradient"),
                           (points_panel(output, width), f"output points (n = {len(output)})")], width, points.domain)
    with atomic_path(out / "contact_sheet.png") as tmp:
        sheet.save(tmp, format="PNG")
    seconds["write"] = time.perf_counter() - clock
    seconds["total"] = time.perf_counter() - started

    summary = {
        "input": {"points": str(args.points), "n": len(points), "domain": list(points.domain)},
        "model": {"path": str(model_path), "name": model.metadata.get("name"), "trained_points_per_ink": model.points_per_ink,
                  "threads": args.threads, "raster_side_px": raster_side},
        "points_per_ink": args.points_per_ink,
        "inferred_map": {"width": inferred.width, "height": inferred.height,
                         "mean_density": round(float(inferred.density().mean()), 4)},
        "edit": {"preset": args.preset, "ab": [round(float(v), 2) for v in presets[args.preset]],
                 "background": f"inferred density < {args.background_below:g}",
                 "background_fraction": round(float(region.mean()), 4),
                 "gradient": {"top": args.gradient[0], "bottom": args.gradient[1], "mode": "set"},
                 "mean_density": round(float(edited.density().mean()), 4)},
        "output": {"n": len(output), "schedule": result.schedule, "iterations": result.iterations, "seed": args.seed,
                   "final_loss": round(result.final_loss, 5), **density_fidelity(output, edited)},
        "seconds": {stage: round(value, 3) for stage, value in seconds.items()},
        "files": [str(out / name) for name in OUTPUTS],
    }
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    return summary


def report(summary: dict) -> str:
    s, edit = summary["seconds"], summary["edit"]
    return "\n".join([
        f"read     {summary['input']['n']} points from {summary['input']['points']} ({s['read']:.2f} s)",
        f"infer    {summary['inferred_map']['width']}x{summary['inferred_map']['height']} map, raster "
        f"{summary['model']['raster_side_px']} px, {summary['points_per_ink']:g} points per ink ({s['infer']:.2f} s)",
        f"edit     background ({100 * edit['background_fraction']:.0f}% of the map) -> {edit['preset']}, density "
        f"{edit['gradient']['top']:g} -> {edit['gradient']['bottom']:g} top to bottom ({s['edit']:.2f} s)",
        f"synth    {summary['output']['n']} points, {summary['output']['iterations']} iterations, density SSIM "
        f"{summary['output']['ssim']:.3f} ({s['synthesize']:.1f} s)",
        f"write    {len(summary['files'])} files ({s['write']:.2f} s); total {s['total']:.1f} s",
        f"contact sheet: {summary['files'][OUTPUTS.index('contact_sheet.png')]}",
    ])


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    threads = torch.get_num_threads()
    with warnings.catch_warnings():
        warnings.simplefilter("always", PatternshopWarning)
        if not args.debug:
            warnings.showwarning = lambda message, *_, **__: print(f"{PROG}: warning: {' '.join(str(message).split())}",
                                                                  file=sys.stderr)
        try:
            model = check_args(args)
            torch.set_num_threads(args.threads)
            summary = run(args, model)
        except (PatternshopError, OSError) as exc:
            if args.debug:
                raise
            print(f"{PROG}: error: {' '.join(str(exc).split())}", file=sys.stderr)
            return 2
        except Exception as exc:  # a bug: one line unless asked
            if args.debug:
                raise
            print(f"{PROG}: internal error: {type(exc).__name__}: {' '.join(str(exc).split())} (rerun with --debug)",
                  file=sys.stderr)
            return 1
        finally:
            torch.set_num_threads(threads)
    print(report(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
