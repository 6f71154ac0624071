"""Subcommands of the ``patternshop`` command, one module per topic, plus shared helpers.

Helpers every command uses the same way: argument types that reject bad numbers
at parse time (exit status 2), output checks before any work, the memory
estimate against ``--max-memory-gb``, and ``--threads``.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
from collections.abc import Iterator
from pathlib import Path

from synthesis import resources
from synthesis.errors import PatternshopError

DEFAULT_MAX_MEMORY_GB = 4.0
GIGABYTE = 1e9
MAX_SEED = 2**32 - 1
THREADS_HELP = ("CPU threads for this process (torch, numba, OpenMP, ONNX Runtime; default 1). 2 help only on an idle "
                "machine with large inputs (100k+ points, 1000+ px maps); on a busy 2-core machine they can make it "
                "several times slower")
_THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")


# --- argument types (argparse reports their errors as one line, exit status 2) ----------------------------
def _number(text: str, kind: type) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def finite_float(text: str) -> float:
    """A finite number."""
    return float(_number(text, float))


def positive_int(text: str) -> int:
    """An integer >= 1."""
    value = _number(text, int)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return int(value)


def non_negative_int(text: str) -> int:
    """An integer >= 0."""
    value = _number(text, int)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {value}")
    return int(value)


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = _number(text, float)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {value:g}")
    return value


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    value = _number(text, float)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {value:g}")
    return value


def seed(text: str) -> int:
    """A random seed in [0, 2**32 - 1]."""
    value = _number(text, int)
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be an integer from 0 to {MAX_SEED}, got {text}")
    return int(value)


# --- resources ----------------------------------------------------------------------------------------------
def add_max_memory_option(parser: argparse.ArgumentParser) -> None:
    """``--max-memory-gb`` (every command: the limit :func:`check_memory` holds estimates to)."""
    parser.add_argument("--max-memory-gb", type=positive_float, default=DEFAULT_MAX_MEMORY_GB, metavar="GB",
                        help=f"refuse work whose memory, estimated from the inputs before starting, exceeds GB "
                        f"(default {DEFAULT_MAX_MEMORY_GB:g})")


def add_threads_option(parser: argparse.ArgumentParser) -> None:
    """``--threads`` (compute commands); ``main`` runs the command inside :func:`thread_limit`."""
    parser.add_argument("--threads", type=positive_int, default=1, metavar="N", help=THREADS_HELP)


@contextlib.contextmanager
def thread_limit(threads: int) -> Iterator[None]:
    """Use ``threads`` CPU threads inside the block: OpenMP/BLAS/numba variables (read when those libraries load),
    and torch and numba if already loaded; the previous settings come back after it (``main`` may run in-process)."""
    saved_variables = {variable: os.environ.get(variable) for variable in _THREAD_VARIABLES}
    torch, numba = sys.modules.get("torch"), sys.modules.get("numba")
    saved_torch = torch.get_num_threads() if torch is not None else None
    saved_numba = numba.get_num_threads() if numba is not None else None
    for variable in _THREAD_VARIABLES:
        os.environ[variable] = str(threads)
    if torch is not None:
        torch.set_num_threads(threads)
    if numba is not None:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        yield
    finally:
        for variable, value in saved_variables.items():
            if value is None:
                os.environ.pop(variable, None)
            else:
                os.environ[variable] = value
        if saved_torch is not None:
            torch.set_num_threads(saved_torch)
        if saved_numba is not None:
            numba.set_num_threads(saved_numba)


def check_memory(args: argparse.Namespace, needed_bytes: float, work: str) -> None:
    """Refuse ``work`` (e.g. "a 20000x20000 px map") when its estimated memory exceeds ``--max-memory-gb``.

    Raises:
        PatternshopError: naming the estimate, the limit and the option that lifts it.
    """
    if needed_bytes > args.max_memory_gb * GIGABYTE:
        raise PatternshopError(f"{work} needs about {needed_bytes / GIGABYTE:.3g} GB of memory, over the limit of "
                               f"{args.max_memory_gb:g} GB (raise it with --max-memory-gb)")


def map_pixels(path: str | Path) -> int:
    """Pixel count of a map file, from its header only (decoding nothing)."""
    from synthesis.mapio import map_size

    width, height = map_size(path)
    return width * height


def check_map_input(args: argparse.Namespace, path: str | Path) -> int:
    """Refuse a map whose reading would exceed ``--max-memory-gb``; returns its pixel count."""
    pixels = map_pixels(path)
    check_memory(args, resources.map_bytes(pixels), f"reading the {pixels:,}-pixel map {path}")
    return pixels


def check_point_file(args: argparse.Namespace, path: str | Path) -> None:
    """Refuse a point file whose reading would exceed ``--max-memory-gb`` (estimated from its size on disk).

    A missing file passes: the reader names it.
    """
    path = Path(path)
    if path.is_file():
        size = path.stat().st_size
        check_memory(args, resources.point_file_bytes(size, npy=path.suffix.lower() == ".npy"), f"reading {path} ({size / 1e6:.3g} MB)")


# --- inputs and outputs -------------------------------------------------------------------------------------
def check_output(output: str | Path, *inputs: str | Path, suffixes: tuple[str, ...] = ()) -> Path:
    """Validate an output path before any work: right suffix, not a folder, not one of the inputs, and an
    existing folder that takes a new file (:func:`synthesis.atomic.check_writable`).

    Raises:
        PatternshopError: the suffix is wrong, the output would overwrite an input, or the folder is not writable.
        FileNotFoundError: the folder is missing.
    """
    from synthesis.atomic import check_writable

    output = Path(output)
    if suffixes and output.suffix.lower() not in suffixes:
        raise PatternshopError(f"{output}: output must end in {' or '.join(suffixes)}")
    if output.is_dir():
        raise PatternshopError(f"{output}: is a folder")
    for source in inputs:
        if Path(source).resolve() == output.resolve():
            raise PatternshopError(f"{output}: output would overwrite the input")
    return check_writable(output)


def check_map_output(output: str | Path, *inputs: str | Path) -> Path:
    """Validate a map output before any work: a CIELAB ``.tif``/``.tiff`` or channel PNGs ``NAME.L.png``, not an input.

    Raises:
        PatternshopError: another suffix, a missing folder, or an output that would overwrite an input.
    """
    from synthesis.mapio import TIFF_SUFFIXES, channel_paths, is_channel_path

    output = Path(output)
    if is_channel_path(output):
        for target in channel_paths(output):
            check_output(target, *inputs)
        return output
    if output.suffix.lower() not in TIFF_SUFFIXES:
        raise PatternshopError(f"{output}: write a map as a CIELAB .tif or as channel PNGs NAME.L.png "
                               "(NAME.a.png and NAME.b.png come with it); an sRGB .png is only a preview (--preview)")
    return check_output(output, *inputs)


def check_palette_file(path: str | None) -> None:
    """Check a ``--palette`` file before any work: it exists and is an ``.npz`` archive (zip).

    Raises:
        PatternshopError: missing, or not a zip archive.
    """
    if path is None:
        return
    try:
        with open(path, "rb") as handle:
            magic = handle.read(4)
    except OSError as exc:
        raise PatternshopError(f"{path}: palette not readable ({exc.strerror})") from None
    if magic != b"PK\x03\x04":
        raise PatternshopError(f"{path}: not a palette (a palette is an .npz archive, like synthesis/assets/palette.npz)")
