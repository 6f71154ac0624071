"""``studio``: the local browser editor (:mod:`patternshop.studio`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from patternshop.commands import check_map_input, check_point_file, positive_float, positive_int

def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"a port is from 0 to 65535, got {value}")
    return value


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """Add ``studio``."""
    parser = subparsers.add_parser(
        "studio",
        parents=[common],
        help="edit a map in the browser and watch its points form",
        description="Start Patternshop Studio, a local web editor: paint density and correlation, pick "
        "correlations from the palette by their look, synthesise and see the points form. The server listens "
        "on 127.0.0.1, prints its URL (with an access token) and opens the browser. The map, its edit history "
        "and the settings are saved in the project folder after every edit, so a reload or a restart reopens "
        "where you were.",
    )
    parser.add_argument("file", nargs="?", help="a map to open (CIELAB TIFF or sRGB PNG/JPEG), a point file (.txt, "
                        ".csv, .npy: its map is inferred by the network) or, with --photo, a photo; without it the "
                        "project's last map, or a blank map")
    parser.add_argument("--photo", action="store_true", help="FILE is a photo: open the map whose stipple "
                        "reproduces its tone (as 'patternshop from-image' with its defaults, blue noise)")
    parser.add_argument("--port", type=_port, default=8765, help="port to listen on (default 8765, or the next free "
                        "one; 0: any free port)")
    parser.add_argument("--host", default="127.0.0.1", help="interface to listen on (default 127.0.0.1; anything "
                        "else exposes the studio to the network: the token is then all that protects it)")
    parser.add_argument("--no-browser", action="store_true", help="do not open a browser")
    parser.add_argument("--project", metavar="DIR", help="project folder (default: patternshop/studio in the "
                        "user's data directory, e.g. ~/.local/share/patternshop/studio)")
    parser.add_argument("--max-upload-mb", type=positive_float, default=100.0, metavar="MB",
                        help="largest file the page may upload (default 100)")
    parser.add_argument("--history", type=positive_int, default=100, metavar="N", help="undo steps kept (default 100)")
    parser.set_defaults(func=run_studio)


def run_studio(args: argparse.Namespace) -> None:
    import warnings

    from patternshop.studio.project import Project, default_project_dir
    from patternshop.studio.server import LOOPBACK_HOSTS, serve
    from synthesis.errors import PatternshopWarning

    if args.host not in LOOPBACK_HOSTS:
        warnings.warn(f"listening on {args.host}: other machines can reach the studio; only its token protects it",
                      PatternshopWarning, stacklevel=1)
    lab = None
    if args.file is not None:
        from patternshop import api
        from synthesis.points import NPY_SUFFIX, TEXT_SUFFIXES

        if args.photo:
            lab = api.from_image(args.file).lab
        elif Path(args.file).suffix.lower() in TEXT_SUFFIXES + (NPY_SUFFIX,):
            check_point_file(args, args.file)
            print(f"inferring the map of {args.file} with the network ...", flush=True)
            lab = api.infer(args.file).lab_map.lab
        else:
            check_map_input(args, args.file)
            lab = api.read_map(args.file).lab
    project = Project(Path(args.project) if args.project else default_project_dir(), history_limit=args.history)
    try:
        if lab is not None:
            project.open_map(lab, Path(args.file).name)
        elif not project.has_map:
            from patternshop import api

            project.open_map(api.uniform_map(512, density=0.3, correlation="blue").lab, "blank map")
        serve(project, host=args.host, port=args.port, open_browser=not args.no_browser,
              max_upload_bytes=int(args.max_upload_mb * 1e6), max_memory_gb=args.max_memory_gb,
              announce=lambda line: print(line, flush=True))
    finally:
        project.close()
