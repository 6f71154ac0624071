"""Palette commands: ``palette`` (picture and preset list) and ``analyze`` (a pattern's correlation)."""

from __future__ import annotations

import argparse
import json
import sys

from patternshop.commands import (add_threads_option, check_memory, check_output, check_palette_file, check_point_file,
                                  positive_int)
from synthesis.resources import analysis_bytes, palette_picture_bytes, render_bytes, synthesis_bytes

CONTINUOUS_MAP_PIXELS = 256 * 256  # the continuous palette synthesises on the 256 x 256 ab plane


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """Add ``palette`` and ``analyze``."""
    palette = subparsers.add_parser(
        "palette",
        parents=[common],
        help="draw the correlation palette (ab plane with example patterns), or list the presets",
        description="Draw the ab plane of the correlation palette as a grid of example patterns, each on a "
        "background of its colour, with the named presets marked, so you can pick a colour by its look. "
        "With --list, print the presets as JSON instead: {\"blue\": {\"a\": .., \"b\": .., \"hue\": .., \"chroma\": ..}, ...}.",
    )
    palette.add_argument("output", nargs="?", help="output .png (not needed with --list)")
    palette.add_argument("--list", action="store_true", help="print the presets as JSON and exit")
    palette.add_argument("--grid", type=positive_int, default=9, metavar="N", help="cells per side (default 9)")
    palette.add_argument("--cell", type=positive_int, default=112, metavar="PX", help="cell size in pixels (default 112)")
    palette.add_argument("--continuous", action="store_true",
                         help="draw one synthesised pattern whose correlation varies continuously over the ab plane (paper Fig. 4)")
    palette.add_argument("--points", type=positive_int, default=20_000, metavar="N", help="points of the continuous picture (default 20000)")
    palette.add_argument("--palette", metavar="FILE", help="palette asset (default: the shipped one)")
    add_threads_option(palette)
    palette.set_defaults(func=run_palette)

    analyze = subparsers.add_parser(
        "analyze",
        parents=[common],
        help="measure a pattern's PCF and spectrum and find its palette colour",
        description="Estimate the pair correlation function (radii in units of r_max, border handled by "
        "minus sampling) and the radial power spectrum of a stationary pattern, decode its palette colour "
        "(a, b) and name the nearest preset.",
    )
    analyze.add_argument("points", help="point file (.txt, .csv, .npy)")
    analyze.add_argument("--plot", metavar="PNG", help="write a plot of the PCF and the spectrum")
    analyze.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    analyze.add_argument("--domain", nargs=2, type=float, metavar=("W", "H"), help="domain of the points (default: from the file, else 1 1)")
    analyze.add_argument("--palette", metavar="FILE", help="palette asset (default: the shipped one)")
    analyze.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_threads_option(analyze)
    analyze.set_defaults(func=run_analyze)


def run_palette(args: argparse.Namespace) -> None:
    from synthesis.errors import PatternshopError
    from synthesis.palette import load_palette

    check_palette_file(args.palette)
    if args.list:
        from patternshop.api import presets
        from synthesis.palette import hue_chroma

        listing = {}
        for name, (a, b) in presets(args.palette).items():
            hue, chroma = hue_chroma(a, b)
            listing[name] = {"a": a, "b": b, "hue": round(hue, 1), "chroma": round(chroma, 1)}
        print(json.dumps(listing, indent=2))
        return
    if not args.output:
        raise PatternshopError("give an output .png (or --list)")
    if args.grid < 2 or args.cell < 32:
        raise PatternshopError("--grid must be >= 2 and --cell >= 32")
    output = check_output(args.output, suffixes=(".png",))
    size = args.grid * args.cell
    check_memory(args, palette_picture_bytes(size), f"a {size}x{size} px palette picture")
    if args.continuous:
        check_memory(args, synthesis_bytes(CONTINUOUS_MAP_PIXELS, args.points) + render_bytes(size, size),
                     f"a continuous palette of {args.points:,} points")
    from synthesis.palette_image import draw_continuous_palette, draw_palette

    palette = load_palette(args.palette)
    if args.continuous:
        draw_continuous_palette(palette, output, size=size, points=args.points)
    else:
        draw_palette(palette, output, grid=args.grid, cell=args.cell)
    print(f"wrote {output}", file=sys.stderr)


def run_analyze(args: argparse.Namespace) -> None:
    from patternshop import api

    plot = check_output(args.plot, args.points, suffixes=(".png",)) if args.plot else None
    check_palette_file(args.palette)
    check_point_file(args, args.points)
    points = api.read_points(args.points, domain=tuple(args.domain) if args.domain else None)
    check_memory(args, analysis_bytes(len(points)), f"analysing {len(points):,} points")
    result = api.analyze(points, palette=args.palette,  # warns when the pattern lies outside the palette's corpus
                         progress_bar=not args.no_progress and sys.stderr.isatty())
    if plot is not None:
        api.plot_analysis(result, plot)
    if args.json:
        print(json.dumps(result))
        return
    print(f"{args.points}: {result['n']} points, domain {result['domain'][0]:g} x {result['domain'][1]:g}")
    print(f"palette colour: a = {result['a']:.1f}, b = {result['b']:.1f} (hue {result['hue']:.0f} deg, chroma {result['chroma']:.0f})")
    print(f"nearest preset: {result['nearest_preset']}")
    print(f"confidence: {result['confidence']} (nearest corpus exemplar {result['exemplar_distance']:.2f} exemplar spacings away)")
    print("PCF (r / r_max: g): " + ", ".join(f"{r:.2f}: {g:.2f}" for r, g in zip(result["r"][::3], result["pcf"][::3])))
    if plot is not None:
        print(f"wrote {plot}")
