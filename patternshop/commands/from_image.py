"""Map command: ``from-image`` (a photo -> a map whose L reproduces the photo's tone), see :mod:`synthesis.photo`."""

from __future__ import annotations

import argparse
import sys
import textwrap

from patternshop.commands import check_map_output, check_output
from synthesis.conventions import POINTS_PER_INK_MEANING

DESCRIPTION = """\
Make a map from a photo (any image Pillow reads: 8/16-bit grey, RGB, RGBA,
palette; EXIF orientation applied). The map has the photo's pixels, so its
domain is the photo's aspect ratio with the long side 1.

Tone: L = 100 Y, where Y is the photo's LINEAR luminance (sRGB decoded,
Y = 0.2126 R + 0.7152 G + 0.0722 B), not CIELAB L*. Dots add ink linearly in
luminance: points covering a fraction c of the paper leave Y = 1 - c, so a
stipple of density 1 - Y has the photo's tone. A mid grey (sRGB 119, L* = 50,
Y = 0.184) becomes L = 18.4, i.e. density 0.82; read as L = 50 it would print
as light as L* = 76. Photos are mostly dark in linear terms: expect mean
densities of 0.6-0.9, hence many points (see --points of 'synthesize').

Order: levels, then gamma, then invert; transparent pixels are paper (no
points). Correlation: --preset/--ab everywhere (default: the blue preset),
then --labels/--label or --mask on top."""

EPILOG = """\
Examples:
  patternshop from-image photo.jpg out/photo.tif --preview out/photo_map.png
  patternshop from-image photo.jpg out/photo.tif --levels 10 240 --gamma 0.8 --preset green
  patternshop from-image seg.png out/seg.tif --labels seg.png --label 0=blue --label 255=red
  patternshop from-image photo.jpg out/photo.tif --labels seg.png --label '#ff0000=-20,40'
  patternshop from-image photo.jpg out/photo.tif --mask sky.png --mask-preset white
  patternshop synthesize out/photo.tif out/photo.txt --points 20000 --png out/photo.png
CORRELATION is a preset name ('patternshop palette --list') or 'A,B'."""


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """Add ``from-image``."""
    command = subparsers.add_parser(
        "from-image",
        parents=[common],
        help="make a map from a photo: L from linear luminance, correlation from a preset, labels or a mask",
        description=DESCRIPTION + "\n\n" + textwrap.fill(f"--points-per-ink of 'synthesize': {POINTS_PER_INK_MEANING}.", 79),
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    command.add_argument("photo", help="input photo (PNG, JPEG, TIFF, ... any image Pillow reads)")
    command.add_argument("output", help="output map: CIELAB .tif, or NAME.L.png for three channel PNGs")
    tone = command.add_argument_group("tone")
    tone.add_argument("--levels", nargs=2, type=float, metavar=("BLACK", "WHITE"), default=(0.0, 255.0),
                      help="black and white points as grey values on the 0-255 scale of the photo (sRGB-encoded, "
                      "what an editor's colour picker shows): BLACK and darker become full ink, WHITE and lighter "
                      "no points, stretched between as an editor's Levels would (default 0 255)")
    tone.add_argument("--gamma", type=float, default=1.0, metavar="G",
                      help="tone curve Y' = Y^G applied after --levels: G > 1 darkens the mid-tones (more points), "
                      "G < 1 lightens them (default 1)")
    tone.add_argument("--invert", action="store_true",
                      help="white dots on black paper: density = Y' instead of 1 - Y'")
    correlation = command.add_argument_group("correlation")
    base = correlation.add_mutually_exclusive_group()
    base.add_argument("--preset", metavar="NAME", help="correlation of the whole map (default: blue)")
    base.add_argument("--ab", nargs=2, type=float, metavar=("A", "B"), help="correlation of the whole map as an a,b colour")
    regions = correlation.add_mutually_exclusive_group()
    regions.add_argument("--labels", metavar="IMAGE",
                         help="label image of the photo's size (grey, palette or colour): pixels of a label named by "
                         "--label get its correlation, the others keep --preset/--ab")
    regions.add_argument("--mask", metavar="IMAGE",
                         help="greyscale mask of the photo's size: white gets --mask-preset/--mask-ab, black keeps "
                         "--preset/--ab, grey blends")
    correlation.add_argument("--label", action="append", default=[], metavar="KEY=CORRELATION",
                             help="with --labels (repeatable): KEY is a grey value or palette index (0, 255, ...) or a "
                             "colour #rrggbb; e.g. --label 0=blue --label '#ff0000=49,2'")
    mask_colour = correlation.add_mutually_exclusive_group()
    mask_colour.add_argument("--mask-preset", metavar="NAME", help="with --mask: the correlation where the mask is white")
    mask_colour.add_argument("--mask-ab", nargs=2, type=float, metavar=("A", "B"), help="with --mask: the same as an a,b colour")
    output = command.add_argument_group("output")
    output.add_argument("--max-side", type=int, default=1024, metavar="PX",
                        help="downsample larger photos (area average of linear luminance) so the map's long side is "
                        "at most PX pixels, 1-4096 (default 1024)")
    output.add_argument("--bits", type=int, choices=(8, 16), default=16, help="bits per sample of a TIFF output (default 16)")
    output.add_argument("--preview", metavar="PNG", help="also write an sRGB PNG preview of the map")
    output.add_argument("--palette", metavar="FILE", help="palette asset for preset names (default: the shipped one)")
    command.set_defaults(func=run_from_image)


def run_from_image(args: argparse.Namespace) -> None:
    from patternshop import api
    from synthesis.conventions import POINTS_PER_INK, full_ink_points
    from synthesis.errors import PatternshopError
    from synthesis.mapio import write_map, write_preview

    if args.label and not args.labels:
        raise PatternshopError("--label needs --labels IMAGE")
    if args.labels and not args.label:
        raise PatternshopError("--labels needs at least one --label KEY=CORRELATION")
    mask_colour = args.mask_preset is not None or args.mask_ab is not None
    if bool(args.mask) != mask_colour:
        raise PatternshopError("--mask and --mask-preset/--mask-ab go together")
    inputs = [p for p in (args.photo, args.labels, args.mask) if p]
    output = check_map_output(args.output, *inputs)
    preview = check_output(args.preview, *inputs, args.output, suffixes=(".png",)) if args.preview else None

    label_correlations = {}
    for spec in args.label:
        key, equals, value = spec.partition("=")
        if not equals:
            raise PatternshopError(f"--label {spec!r}: write KEY=CORRELATION, e.g. 0=blue or '#ff0000=49,2'")
        label_correlations[key] = value
    mask_correlation = tuple(args.mask_ab) if args.mask_ab is not None else args.mask_preset
    lab_map = api.from_image(args.photo, correlation=tuple(args.ab) if args.ab is not None else args.preset or "blue",
                             levels=args.levels, gamma=args.gamma, invert=args.invert, labels=args.labels,
                             label_correlations=label_correlations, mask=args.mask, mask_correlation=mask_correlation,
                             max_side=args.max_side, palette=args.palette)
    if preview is None:
        write_map(lab_map, output, bits=args.bits)
    else:  # the preview is renamed into place only once the map is written: both or neither
        from synthesis.atomic import atomic_path

        with atomic_path(preview) as tmp:
            write_preview(lab_map, tmp)
            write_map(lab_map, output, bits=args.bits)
    w, h = lab_map.domain
    density = float(lab_map.density().mean())
    print(f"wrote {output} ({lab_map.width}x{lab_map.height} px, domain {w:.4g} x {h:.4g}; mean density {density:.3f}: "
          f"'synthesize' makes ~{round(full_ink_points(POINTS_PER_INK, lab_map.domain) * density):,} points by default, "
          "fewer with --points)",
          file=sys.stderr)

