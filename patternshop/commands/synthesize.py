"""``synthesize``: a map in, a point pattern out (points, PNG, SVG, report)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from patternshop.commands import (add_threads_option, check_memory, check_output, check_palette_file, map_pixels,
                                  non_negative_float, positive_float, positive_int, seed)
from synthesis.atomic import all_or_nothing, atomic_write_text
from synthesis.resources import render_bytes, synthesis_bytes
from synthesis.conventions import POINTS_PER_INK, POINTS_PER_INK_MEANING
from synthesis.errors import PatternshopError



def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """Add ``synthesize``."""
    parser = subparsers.add_parser(
        "synthesize",
        parents=[common],
        help="synthesise a point pattern from a map",
        description="Place points so that their density follows the map's L channel and their correlation "
        "its a,b colour (edge-aware PCF matching, paper §6). The point count defaults to "
        "points-per-ink x area x mean density (50,000 x area x mean(1 - L/100)). A .txt output records the "
        "points per ink in its header (# points_per_ink: P, also with --points), so that 'infer' reads it at "
        "that scale; .csv and .npy outputs carry no header.",
    )
    parser.add_argument("map", help="input map (CIELAB/ICCLAB TIFF, channel PNGs NAME.L.png, or an sRGB image)")
    parser.add_argument("output", help="output points (.txt, .csv or .npy)")
    parser.add_argument("--svg", metavar="FILE", help="also write an SVG of circles (pen plotters, vpype)")
    parser.add_argument("--png", metavar="FILE", help="also write a PNG rendering")
    parser.add_argument("--points", type=positive_int, metavar="N", help="number of points (default: from the ink)")
    parser.add_argument("--points-per-ink", type=positive_float, default=POINTS_PER_INK, metavar="K",
                        help=f"{POINTS_PER_INK_MEANING} (default {POINTS_PER_INK})")
    parser.add_argument("--schedule", choices=("fast",), default="fast", help="optimisation schedule (only fast: 180 iterations, every point a centre at each)")
    parser.add_argument("--iterations", type=positive_int, metavar="K", help="override the schedule's iteration count")
    parser.add_argument("--seed", type=seed, default=0, help="random seed, 0 to 2^32-1 (default 0); same seed, same points")
    parser.add_argument("--dot-sizes", action="store_true", help="give each point a radius so the rendering matches the L channel's tone")
    parser.add_argument("--report", metavar="JSON", help="write a JSON report (n, seconds, iterations, final_loss, ...)")
    parser.add_argument("--png-width", type=positive_int, default=1024, metavar="PX", help="PNG width in pixels (default 1024)")
    parser.add_argument("--svg-width", type=positive_float, default=200.0, metavar="MM", help="SVG width in millimetres (default 200)")
    parser.add_argument("--pen-width", type=positive_float, metavar="MM", help="SVG: outline circles with this pen width instead of filling them")
    parser.add_argument("--min-radius", type=non_negative_float, default=0.0, metavar="MM", help="SVG: smallest circle radius (default 0)")
    parser.add_argument("--max-radius", type=positive_float, metavar="MM", help="SVG: largest circle radius")
    parser.add_argument("--palette", metavar="FILE", help="palette asset (default: the shipped one)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--preview-every", type=positive_int, metavar="K",
                        help="write the points so far to the preview file at the start (the density-matched start, "
                        "within a second of the map being read) and every K iterations, for an editor that shows the "
                        "points while they form. Each write is atomic: the file is always a complete point file. It is "
                        "removed when the run ends, by Ctrl+C too; a run killed with kill -9 cannot remove it, so its last "
                        "preview stays (and the temporary file of a write it was killed in) until the next run with this "
                        "preview file replaces it (and removes that temporary)")
    parser.add_argument("--preview", metavar="FILE", help="preview file for --preview-every (default: OUTPUT with "
                        "'.preview' before its suffix, e.g. points.preview.txt; .npy writes fastest)")
    add_threads_option(parser)
    parser.set_defaults(func=run_synthesize)


def _preview_path(output: str) -> str:
    """``points.txt`` -> ``points.preview.txt``."""
    path = Path(output)
    return str(path.with_name(f"{path.stem}.preview{path.suffix}"))


def run_synthesize(args: argparse.Namespace) -> None:
    from synthesis.points import NPY_SUFFIX, TEXT_SUFFIXES

    output = check_output(args.output, args.map, suffixes=TEXT_SUFFIXES + (NPY_SUFFIX,))
    svg = check_output(args.svg, args.map, suffixes=(".svg",)) if args.svg else None
    png = check_output(args.png, args.map, suffixes=(".png",)) if args.png else None
    report_path = check_output(args.report, args.map, suffixes=(".json",)) if args.report else None
    if args.preview and not args.preview_every:
        raise PatternshopError("--preview needs --preview-every K")
    preview = check_output(args.preview or _preview_path(args.output), args.map, args.output,
                           suffixes=TEXT_SUFFIXES + (NPY_SUFFIX,)) if args.preview_every else None
    if args.max_radius is not None and args.max_radius < args.min_radius:
        raise PatternshopError(f"--max-radius {args.max_radius:g} is smaller than --min-radius {args.min_radius:g}")
    check_palette_file(args.palette)
    pixels = map_pixels(args.map)
    check_memory(args, synthesis_bytes(pixels, args.points or 0), f"synthesis of {args.points:,} points" if args.points else f"synthesis on a {pixels:,}-pixel map")
    if png is not None:
        check_memory(args, render_bytes(args.png_width, args.png_width), f"a {args.png_width} px wide PNG")

    from patternshop import api

    lab_map = api.read_map(args.map)
    n = args.points if args.points is not None else api.point_count(lab_map, args.points_per_ink)
    check_memory(args, synthesis_bytes(pixels, n), f"synthesis of {n:,} points"
                 + ("" if args.points is not None else f" ({args.points_per_ink:g} points per ink x area x mean density)"))
    def write_preview(done: int, total: int, xy) -> None:  # noqa: ANN001 - (n, 2) array
        if done % args.preview_every == 0:
            api.write_points(api.PointSet(xy.copy(), lab_map.domain), preview)

    try:
        result = api.synthesize(lab_map, points=n, iterations=args.iterations, seed=args.seed, dot_sizes=args.dot_sizes,
                                schedule=args.schedule, palette=args.palette, threads=args.threads,
                                progress=write_preview if preview is not None else None,
                                progress_bar=not args.no_progress and sys.stderr.isatty())
    finally:
        if preview is not None:
            preview.unlink(missing_ok=True)
    from synthesis.tone import density_fidelity  # after the run: scipy.ndimage's import is not start-up

    points = result.points
    report = result.report() | {"map": args.map, "seed": args.seed, "dot_sizes": args.dot_sizes} | density_fidelity(points, lab_map)
    with all_or_nothing():  # points, PNG, SVG and report replace the old ones together, or none does
        api.write_points(points, output)
        if png is not None:
            api.render_png(points, png, width_px=args.png_width)
        if svg is not None:
            api.write_svg(points, svg, width_mm=args.svg_width, pen_width_mm=args.pen_width,
                          min_radius_mm=args.min_radius, max_radius_mm=args.max_radius)
        if report_path is not None:
            atomic_write_text(report_path, json.dumps(report, indent=2) + "\n")
    print(f"wrote {output}: {report['n']} points ({points.points_per_ink:,.0f} points per ink) in {report['seconds']:.1f} s ({report['iterations']} iterations, "
          f"final loss {report['final_loss']:.4g}, density SSIM {report['ssim']:.3f})", file=sys.stderr)
