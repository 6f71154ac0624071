"""Point-file command: ``points`` (check and convert)."""

from __future__ import annotations

import argparse

from patternshop.commands import check_output, check_point_file


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """Add ``points``."""
    points = subparsers.add_parser(
        "points",
        parents=[common],
        help="check a point file and convert it between .txt, .csv and .npy",
        description="Read a point file, check every line (columns, numbers, domain), print a summary, "
        "and with OUTPUT write it in the format OUTPUT's suffix names.",
    )
    points.add_argument("input", help="point file (.txt, .csv, .npy)")
    points.add_argument("output", nargs="?", help="optional output point file (.txt, .csv, .npy)")
    points.add_argument(
        "--domain",
        nargs=2,
        type=float,
        metavar=("W", "H"),
        help="domain [0,W]x[0,H] the points must lie in, max(W,H)=1 (default: the file's '# domain:' comment, else 1 1)",
    )
    points.set_defaults(func=run_points)


def run_points(args: argparse.Namespace) -> None:
    from synthesis.points import NPY_SUFFIX, TEXT_SUFFIXES, read_points, write_points

    output = check_output(args.output, args.input, suffixes=TEXT_SUFFIXES + (NPY_SUFFIX,)) if args.output else None
    check_point_file(args, args.input)
    points = read_points(args.input, domain=tuple(args.domain) if args.domain else None)
    w, h = points.domain
    radii = "with radii" if points.radius is not None else "no radii"
    print(f"{args.input}: {len(points)} points in [0, {w:g}] x [0, {h:g}], {radii}")
    if output is not None:
        write_points(points, output)
        print(f"wrote {output}")
