"""Batch command: ``convert`` (a folder of point files to maps, or with --resynthesize maps to point files)."""

from __future__ import annotations

import argparse
import sys

from export.infer_config import DEFAULT_INFER, SYMMETRY_CHOICES
from patternshop.commands import check_palette_file, positive_float, positive_int, seed
from synthesis.conventions import POINTS_PER_INK, POINTS_PER_INK_MEANING

EXIT_SOME_FAILED = 1

EPILOG = """\
Bad files do not stop the run: they are listed on stderr at the end; so are
files whose estimated memory exceeds their worker's share of --max-memory-gb.
Ctrl+C stops the workers at once: files finished before it are kept, no
half-written file is left. Point files to maps: each worker reads, infers and
writes whole files; with the shipped model a 20k-point file takes about
0.17 s of one core (the network two thirds), so expect about 6 files/s per
idle core once the workers have started (about 0.3 s each); --workers 2
converted about 10 files/s on a 2-core machine at load 1 (40 files).
Exit status: 0 every file converted or skipped; 1 some files failed (the
others are written); 2 nothing done (bad arguments, missing folder or model)."""


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """Add ``convert``."""
    convert = subparsers.add_parser(
        "convert",
        parents=[common],
        help="batch: infer maps for a folder of point files (or synthesise points for a folder of maps)",
        description="Infer a map for every point file (.txt, .csv, .xy, .pts, .npy) in IN_DIR and write "
        "OUT_DIR/NAME.tif: worker processes each load the network (ONNX Runtime) once, then read, infer and "
        "write files one or a few at a time. With --resynthesize, go the other way: synthesise OUT_DIR/NAME.txt "
        "for every map in IN_DIR (CIELAB/ICCLAB TIFF, channel PNGs NAME.L.png, sRGB images), one map per "
        "worker process. Existing outputs are skipped unless --overwrite.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    convert.add_argument("in_dir", help="folder of point files (of maps with --resynthesize): a path or an fsspec URL "
                         "(file://, s3://, gs://; docs/distributed.md)")
    convert.add_argument("out_dir", help="output folder (created if missing): a path or an fsspec URL")
    convert.add_argument("--model", metavar="FILE", help="ONNX model (default: the shipped patternshop_nn/assets/default.onnx)")
    convert.add_argument("--batch-size", type=positive_int, default=8, metavar="B",
                         help="point files per worker task at most (default 8; fewer in a short run, so that the "
                         "workers finish together)")
    convert.add_argument("--workers", type=positive_int, default=2, metavar="N",
                         help="worker processes, each started once for the run (default 2; 1 works in this process)")
    convert.add_argument("--threads", type=positive_int, default=1, metavar="N",
                         help="CPU threads per worker (ONNX Runtime, or the synthesiser with --resynthesize; default 1): "
                         "on a 2-core machine prefer --workers 2 --threads 1")
    convert.add_argument("--scheduler", metavar="ADDRESS",
                         help="run on the workers of this Dask scheduler (tcp://host:8786) instead of --workers local "
                         "processes; the workers must see IN_DIR and OUT_DIR at the same absolute paths or URLs (docs/distributed.md)")
    convert.add_argument("--bits", type=int, choices=(8, 16), default=16, help="bits per sample of the output TIFFs (default 16)")
    convert.add_argument("--overwrite", action="store_true", help="replace existing outputs instead of skipping their inputs")
    convert.add_argument("--no-progress", action="store_true", help="no progress bar")
    convert.add_argument("--symmetries", type=int, choices=SYMMETRY_CHOICES, default=DEFAULT_INFER.convert_symmetries,
                         help="average each file's network readings over this many symmetries of the square, one network "
                         f"pass each (default {DEFAULT_INFER.convert_symmetries}, for throughput; 8 reads as infer does for "
                         "a model without l_scale)")
    convert.add_argument("--no-denoise", action="store_true",
                         help="keep L's fine detail even where it is only noise (default: L smoothed as infer does; for a "
                         "model without l_scale from two more network readings per file, about twice the time)")
    convert.add_argument("--points-per-ink", type=positive_float, metavar="K",
                         help=f"{POINTS_PER_INK_MEANING}: the scale point files are read at (default: per file as infer "
                         f"does, the header's '# points_per_ink:', else {POINTS_PER_INK} unless the pattern is denser), and maps synthesised at with "
                         f"--resynthesize (default {POINTS_PER_INK}, as synthesize)")
    synthesis = convert.add_argument_group("maps to points (--resynthesize), as in 'patternshop synthesize'")
    synthesis.add_argument("--resynthesize", action="store_true", help="synthesise points for maps instead of inferring maps")
    synthesis.add_argument("--points", type=positive_int, metavar="N", help="points per map (default: from the ink)")
    synthesis.add_argument("--schedule", choices=("fast",), default="fast", help="optimisation schedule (only fast)")
    synthesis.add_argument("--iterations", type=positive_int, metavar="K", help="override the schedule's iteration count")
    synthesis.add_argument("--seed", type=seed, default=0, help="random seed, 0 to 2^32-1, the same for every map (default 0)")
    synthesis.add_argument("--palette", metavar="FILE", help="palette asset (default: the shipped one)")
    convert.set_defaults(func=run_convert)


def run_convert(args: argparse.Namespace) -> int:
    import warnings

    from export.convert import FAILED, SKIPPED
    from patternshop.api import convert
    from synthesis.errors import PatternshopWarning

    check_palette_file(args.palette)
    # api.convert refuses a --model with --resynthesize
    results = convert(args.in_dir, args.out_dir, resynthesize=args.resynthesize, model=args.model, workers=args.workers,
                      threads=args.threads, scheduler=args.scheduler, batch_size=args.batch_size, overwrite=args.overwrite,
                      max_memory_gb=args.max_memory_gb, progress_bar=not args.no_progress and sys.stderr.isatty(),
                      points_per_ink=args.points_per_ink, bits=args.bits, symmetries=args.symmetries,
                      denoise=not args.no_denoise, points=args.points, schedule=args.schedule, iterations=args.iterations,
                      seed=args.seed, palette=args.palette)
    for result in results:
        for note in result.warnings:
            warnings.warn(note, PatternshopWarning, stacklevel=1)
    failed = [r for r in results if r.status == FAILED]
    skipped = sum(r.status == SKIPPED for r in results)
    written = len(results) - len(failed) - skipped
    print(f"wrote {written} of {len(results)} files into {args.out_dir}"
          + (f"; skipped {skipped} whose output exists (--overwrite replaces them)" if skipped else "")
          + (f"; {len(failed)} failed:" if failed else ""), file=sys.stderr)
    for result in failed:
        error = result.error if result.error.startswith(str(result.source)) else f"{result.source}: {result.error}"
        print(f"  {error}", file=sys.stderr)
    return EXIT_SOME_FAILED if failed else 0
