"""Map command: ``edit`` (correlation of a region, density gradient, larger canvas), see :mod:`synthesis.edits`."""

from __future__ import annotations

import argparse
import sys

from patternshop.commands import (check_map_output, check_memory, check_output, check_palette_file, finite_float,
                                  non_negative_int)
from synthesis.resources import edit_bytes

EPILOG = """\
Order: --expand first, then the colour (--preset/--ab), then --gradient, each
inside the region if one is given. Coordinates are map units of the output
map (after --expand): [0,w]x[0,h] with max(w,h)=1, origin top-left, y down.
Density is 1 - L/100 (1 = darkest, most points).

Example, in the style of the paper's Fig. 1: everything outside a subject's
box becomes step noise, its density fading from 0.1 at the top to 0.5 at the
bottom:
  patternshop edit in.tif out.tif --rect 0.3 0.3 0.7 0.7 --invert \\
      --preset step --gradient 0 0 0.1 0 1 0.5"""


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """Add ``edit``."""
    edit = subparsers.add_parser(
        "edit",
        parents=[common],
        help="edit a map: set a region's correlation, add a density gradient, expand the canvas",
        description="Scriptable map edits: set the correlation (a,b colour) of a region to a palette preset "
        "or an explicit colour, set or scale the density along a linear gradient, and add margins to the "
        "canvas. The region is a rectangle or a greyscale mask image (white = edit, black = keep, grey blends).",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    edit.add_argument("map", help="input map (CIELAB/ICCLAB TIFF, channel PNGs NAME.L.png, or an sRGB image)")
    edit.add_argument("output", help="output map: CIELAB .tif, or NAME.L.png for three channel PNGs")
    region = edit.add_mutually_exclusive_group()
    region.add_argument("--rect", nargs=4, type=finite_float, metavar=("X0", "Y0", "X1", "Y1"),
                        help="edit only inside this rectangle (map units)")
    region.add_argument("--region", metavar="MASK", help="edit only where this greyscale mask image (the map's size) is white")
    edit.add_argument("--invert", action="store_true", help="edit outside the rectangle or mask instead")
    colour = edit.add_mutually_exclusive_group()
    colour.add_argument("--preset", metavar="NAME", help="set the correlation to a palette preset (see 'patternshop palette --list')")
    colour.add_argument("--ab", nargs=2, type=finite_float, metavar=("A", "B"), help="set the correlation to this a,b colour (each in [-128, 127])")
    edit.add_argument("--gradient", nargs=6, type=finite_float, metavar=("X0", "Y0", "D0", "X1", "Y1", "D1"),
                      help="linear density gradient: D0 at (X0, Y0), D1 at (X1, Y1), constant beyond the two points")
    edit.add_argument("--gradient-mode", choices=("set", "multiply"), default="set",
                      help="set: density becomes the gradient (D in [0, 1]); multiply: density is scaled by it "
                      "(D are factors), keeping the tone's shape (default set)")
    edit.add_argument("--expand", nargs=4, type=non_negative_int, metavar=("LEFT", "TOP", "RIGHT", "BOTTOM"), help="add margins of these many pixels")
    edit.add_argument("--fill", nargs="+", metavar="FILL",
                      help="the new margins: 'edge' repeats the edge pixels (default), 'content-aware' fills them with "
                      "more of the map's texture (patch-based, like Photoshop's Content-Aware Fill), or a colour L A B")
    edit.add_argument("--seed", type=int, default=0, help="random seed of --fill content-aware (default 0)")
    edit.add_argument("--bits", type=int, choices=(8, 16), default=16, help="bits per sample of a TIFF output (default 16)")
    edit.add_argument("--preview", metavar="PNG", help="also write an sRGB PNG preview of the result")
    edit.add_argument("--palette", metavar="FILE", help="palette asset for --preset (default: the shipped one)")
    edit.set_defaults(func=run_edit)


def _fill(words: list[str] | None) -> str | tuple[float, float, float] | None:
    """--fill's words as :func:`synthesis.edits.expand` takes them: a mode, an (L, a, b) colour, or None."""
    from synthesis.edits import FILL_MODES
    from synthesis.errors import PatternshopError

    if words is None:
        return None
    if len(words) == 1 and words[0] in FILL_MODES:
        return words[0]
    if len(words) != 3:
        raise PatternshopError(f"--fill takes one of {', '.join(FILL_MODES)} or three numbers L A B, got {' '.join(words)}")
    try:
        return tuple(finite_float(word) for word in words)
    except argparse.ArgumentTypeError as exc:
        raise PatternshopError(f"--fill: {exc}") from exc


def run_edit(args: argparse.Namespace) -> None:
    from patternshop import api
    from synthesis.errors import PatternshopError
    from synthesis.atomic import all_or_nothing
    from synthesis.mapio import map_size

    colour = args.preset is not None or args.ab is not None
    if (args.rect or args.region) and not (colour or args.gradient):
        raise PatternshopError("--rect and --region select where --preset, --ab or --gradient apply: give one of them")
    if not (colour or args.gradient or args.expand):
        raise PatternshopError("nothing to do: give --preset or --ab, --gradient, or --expand")
    if args.invert and not (args.rect or args.region):
        raise PatternshopError("--invert needs --rect or --region")
    if args.fill and not args.expand:
        raise PatternshopError("--fill needs --expand")
    output = check_map_output(args.output, args.map)
    preview = check_output(args.preview, args.map, args.output, suffixes=(".png",)) if args.preview else None
    check_palette_file(args.palette)
    width, height = map_size(args.map)
    left, top, right, bottom = args.expand or (0, 0, 0, 0)
    out_width, out_height = width + left + right, height + top + bottom
    check_memory(args, edit_bytes(width * height, out_width * out_height),
                 f"editing into a {out_width}x{out_height} px map")
    ab = api.preset(args.preset, palette=args.palette) if args.preset is not None else args.ab
    lab_map = api.read_map(args.map)
    if args.expand:
        lab_map = api.expand(lab_map, tuple(args.expand), _fill(args.fill), seed=args.seed)
    shape = (lab_map.height, lab_map.width)
    region = (api.rect_region(shape, tuple(args.rect)) if args.rect else api.read_region(args.region, shape) if args.region
              else None)
    if args.invert:
        region = 1.0 - region
    if region is not None and not region.any():
        where = f"the rectangle {tuple(args.rect)}" if args.rect else f"the mask {args.region}"
        raise PatternshopError(f"{where}{' inverted' if args.invert else ''} selects no pixel of the {lab_map.width}x"
                               f"{lab_map.height} px map (domain {lab_map.domain[0]:.4g} x {lab_map.domain[1]:.4g}): "
                               "the edit would change nothing")
    if ab is not None:
        lab_map = api.set_correlation(lab_map, ab, region)
    if args.gradient:
        x0, y0, d0, x1, y1, d1 = args.gradient
        lab_map = api.density_gradient(lab_map, (x0, y0), (x1, y1), (d0, d1), args.gradient_mode, region)
    with all_or_nothing():
        api.write_map(lab_map, output, bits=args.bits)
        if preview is not None:
            api.write_preview(lab_map, preview)
    print(f"wrote {output} ({lab_map.width}x{lab_map.height} px)", file=sys.stderr)
