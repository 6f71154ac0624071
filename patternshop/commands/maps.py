"""Map commands: ``preview``, ``split`` and ``join``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from patternshop.commands import check_map_input, check_memory, check_output, positive_int
from synthesis.errors import PatternshopError
from synthesis.resources import preview_bytes


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """Add ``preview``, ``split`` and ``join``."""
    preview = subparsers.add_parser(
        "preview",
        parents=[common],
        help="write an sRGB PNG preview of a map",
        description="Convert a map (CIELAB/ICCLAB TIFF, channel PNGs, sRGB image) to an 8-bit sRGB PNG "
        "for viewing. Out-of-gamut colours are clipped; the preview is not a lossless map.",
    )
    preview.add_argument("map", help="input map")
    preview.add_argument("output", help="output .png")
    preview.add_argument("--scale", type=positive_int, default=1, metavar="N", help="enlarge N times, nearest neighbour (default 1)")
    preview.set_defaults(func=run_preview)

    split = subparsers.add_parser(
        "split",
        parents=[common],
        help="split a map into three 16-bit greyscale PNGs (L, a, b) for any editor",
        description="Write NAME.L.png, NAME.a.png and NAME.b.png: 16-bit greyscale PNGs holding L/100 and "
        "the latent z = (a+128)/255, (b+128)/255. Any editor (GIMP, Krita, ...) edits them losslessly; "
        "'patternshop join' puts them back together, and every command reads them as a map directly.",
    )
    split.add_argument("map", help="input map")
    split.add_argument("output", help="output name: NAME, NAME.png or NAME.L.png all write NAME.{L,a,b}.png")
    split.set_defaults(func=run_split)

    join = subparsers.add_parser(
        "join",
        parents=[common],
        help="join three channel PNGs back into a CIELAB TIFF",
        description="Read NAME.L.png, NAME.a.png, NAME.b.png (name any of them, or NAME) and write a CIELAB TIFF.",
    )
    join.add_argument("channels", help="NAME, or any of NAME.L.png / NAME.a.png / NAME.b.png")
    join.add_argument("output", help="output .tif")
    join.add_argument("--bits", type=int, choices=(8, 16), default=16, help="bits per sample of the TIFF (default 16)")
    join.set_defaults(func=run_join)


def run_preview(args: argparse.Namespace) -> None:
    from synthesis.mapio import read_map, write_preview

    output = check_output(args.output, args.map, suffixes=(".png",))
    pixels = check_map_input(args, args.map)
    check_memory(args, preview_bytes(pixels, args.scale),
                 f"a preview of {pixels * args.scale**2:,} pixels (--scale {args.scale})")
    lab_map = read_map(args.map)
    write_preview(lab_map, output, scale=args.scale)
    print(f"wrote {output} ({lab_map.width * args.scale}x{lab_map.height * args.scale} px)", file=sys.stderr)


def run_split(args: argparse.Namespace) -> None:
    from synthesis.mapio import TIFF_SUFFIXES, channel_paths, read_map, write_channels

    if Path(args.output).suffix.lower() in (*TIFF_SUFFIXES, ".jpg", ".jpeg"):
        raise PatternshopError(f"{args.output}: split writes NAME.L.png, NAME.a.png, NAME.b.png: give NAME")
    for target in channel_paths(args.output):
        check_output(target, args.map)
    check_map_input(args, args.map)
    paths = write_channels(read_map(args.map), args.output)
    print("wrote " + ", ".join(str(p) for p in paths), file=sys.stderr)


def run_join(args: argparse.Namespace) -> None:
    from synthesis.mapio import TIFF_SUFFIXES, channel_paths, read_channels, write_tiff

    output = check_output(args.output, suffixes=TIFF_SUFFIXES)
    check_map_input(args, channel_paths(args.channels)[0])
    write_tiff(read_channels(args.channels), output, bits=args.bits)
    print(f"wrote {output} ({args.bits}-bit CIELAB)", file=sys.stderr)
