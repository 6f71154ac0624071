"""``synthesize``: a map in, a point pattern out (points, PNG, SVG, report)."""

from __future__ import annotations

import argparse
import json
import sys

from patternshop.commands import check_output


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """Add ``synthesize``."""
    parser = subparsers.add_parser(
        "synthesize",
        parents=[common],
        help="synthesise a point pattern from a map",
        description="Place points so that their density follows the map's L channel and their correlation "
        "its a,b colour (edge-aware PCF matching, paper §6). The point count defaults to "
        "points-per-ink x mean density (50,000 x mean(1 - L/100)).",
    )
    parser.add_argument("map", help="input map (CIELAB/ICCLAB TIFF, channel PNGs NAME.L.png, or an sRGB image)")
    parser.add_argument("output", help="output points (.txt, .csv or .npy)")
    parser.add_argument("--svg", metavar="FILE", help="also write an SVG of circles (pen plotters, vpype)")
    parser.add_argument("--png", metavar="FILE", help="also write a PNG rendering")
    parser.add_argument("--points", type=int, metavar="N", help="number of points (default: from the ink)")
    parser.add_argument("--points-per-ink", type=float, default=50_000, metavar="K", help="points for a fully black map (default 50000)")
    parser.add_argument("--schedule", choices=("fast",), default="fast", help="optimisation schedule (only fast: the paper's 5,000-iteration schedule measured worse at 12x the cost and was removed)")
    parser.add_argument("--iterations", type=int, metavar="K", help="override the schedule's iteration count")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0); same seed, same points")
    parser.add_argument("--dot-sizes", action="store_true", help="give each point a radius so the rendering matches the L channel's tone")
    parser.add_argument("--report", metavar="JSON", help="write a JSON report (n, seconds, iterations, final_loss, ...)")
    parser.add_argument("--png-width", type=int, default=1024, metavar="PX", help="PNG width in pixels (default 1024)")
    parser.add_argument("--svg-width", type=float, default=200.0, metavar="MM", help="SVG width in millimetres (default 200)")
    parser.add_argument("--pen-width", type=float, metavar="MM", help="SVG: outline circles with this pen width instead of filling them")
    parser.add_argument("--min-radius", type=float, default=0.0, metavar="MM", help="SVG: smallest circle radius (default 0)")
    parser.add_argument("--max-radius", type=float, metavar="MM", help="SVG: largest circle radius")
    parser.add_argument("--palette", metavar="FILE", help="palette asset (default: the shipped one)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=run_synthesize)


def run_synthesize(args: argparse.Namespace) -> None:
    from synthesis.mapio import read_map
    from synthesis.palette import load_palette
    from synthesis.points import NPY_SUFFIX, TEXT_SUFFIXES, write_points
    from synthesis.render import render_png, write_svg
    from synthesis.synthesize import point_count, synthesize
    from synthesis.tone import density_fidelity, dot_sizes

    output = check_output(args.output, args.map, suffixes=TEXT_SUFFIXES + (NPY_SUFFIX,))
    svg = check_output(args.svg, args.map, suffixes=(".svg",)) if args.svg else None
    png = check_output(args.png, args.map, suffixes=(".png",)) if args.png else None
    report_path = check_output(args.report, args.map, suffixes=(".json",)) if args.report else None
    lab_map = read_map(args.map)
    n = args.points if args.points is not None else point_count(lab_map, args.points_per_ink)
    result = synthesize(lab_map, n=n, palette=load_palette(args.palette), schedule=args.schedule,
                        iterations=args.iterations, seed=args.seed, progress=not args.no_progress and sys.stderr.isatty())
    points = dot_sizes(result.points, lab_map) if args.dot_sizes else result.points
    write_points(points, output)
    if png is not None:
        render_png(points, png, width_px=args.png_width)
    if svg is not None:
        write_svg(points, svg, width_mm=args.svg_width, pen_width_mm=args.pen_width,
                  min_radius_mm=args.min_radius, max_radius_mm=args.max_radius)
    report = result.report() | {"map": args.map, "seed": args.seed, "dot_sizes": args.dot_sizes} | density_fidelity(points, lab_map)
    if report_path is not None:
        from synthesis.atomic import atomic_write_text

        atomic_write_text(report_path, json.dumps(report, indent=2) + "\n")
    print(f"wrote {output}: {report['n']} points in {report['seconds']:.1f} s ({report['iterations']} iterations, "
          f"final loss {report['final_loss']:.4g}, density SSIM {report['ssim']:.3f})", file=sys.stderr)
