"""The ``patternshop`` command: one parser, subcommands registered by modules.

Each module in :data:`COMMAND_MODULES` has ``register(subparsers, common)`` that
adds its subcommands with ``parents=[common]`` and sets ``func`` to a handler
``handler(args) -> int | None``. Handlers import heavy libraries lazily so that
``patternshop --help`` stays fast.

Errors a user can cause (:class:`~synthesis.errors.PatternshopError`, file
system errors) are printed as one line on stderr with exit status 2; other
exceptions are bugs: one line and exit status 1. ``--debug`` shows tracebacks.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import os
import sys
import warnings
from collections.abc import Sequence

from patternshop import __version__
from patternshop.commands import add_max_memory_option, thread_limit

COMMAND_MODULES = ("patternshop.commands.maps", "patternshop.commands.points", "patternshop.commands.palette", "patternshop.commands.synthesize",
                   "patternshop.commands.network", "patternshop.commands.convert", "patternshop.commands.edit",
                   "patternshop.commands.from_image", "patternshop.commands.studio")
EXIT_USER_ERROR = 2
EXIT_BUG = 1
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141

DESCRIPTION = """\
Edit point patterns as images. A map is a CIELAB image: L is the density
(dark = many points, density = 1 - L/100), the a,b colour is the correlation
(blue, green, clustered noise ...). Edit maps in any image editor; Patternshop
turns points into maps and maps into points."""

EPILOG = """\
Maps: CIELAB TIFF (8/16-bit, as Photoshop and ImageMagick write them), ICCLAB
TIFF, channel PNGs NAME.L.png/NAME.a.png/NAME.b.png (for editors without a Lab
mode), or sRGB PNG/JPEG (converted, with a warning).
Points: text or CSV 'x y [radius]' in [0,w]x[0,h] (max(w,h)=1, origin top-left,
y down) or .npy. Run 'patternshop COMMAND --help' for a command's options."""


class OneLineErrorParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line on stderr, exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    """The full parser with every registered subcommand."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks on errors")
    add_max_memory_option(common)
    parser = OneLineErrorParser(
        prog="patternshop",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"patternshop {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineErrorParser)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(subparsers, common)
    return parser


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:  # noqa: ANN001
    print(f"patternshop: warning: {_one_line(message)}", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    from synthesis.errors import PatternshopError, PatternshopWarning

    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_USER_ERROR
    with warnings.catch_warnings():
        warnings.simplefilter("always", PatternshopWarning)
        if not args.debug:
            warnings.showwarning = _show_warning
        try:
            with thread_limit(args.threads) if "threads" in args else contextlib.nullcontext():
                return int(args.func(args) or 0)
        except BrokenPipeError:  # e.g. `patternshop analyze --json x | head`: the reader left
            sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - keep the interpreter from complaining at exit
            return EXIT_BROKEN_PIPE
        except (PatternshopError, OSError) as exc:
            if args.debug:
                raise
            print(f"patternshop {args.command}: error: {_one_line(exc)}", file=sys.stderr)
            return EXIT_USER_ERROR
        except MemoryError as exc:  # an estimate was too low: still the user's input size, not a bug
            if args.debug:
                raise
            print(f"patternshop {args.command}: error: out of memory ({_one_line(exc) or 'no details'}): use smaller inputs",
                  file=sys.stderr)
            return EXIT_USER_ERROR
        except KeyboardInterrupt:
            print(f"patternshop {args.command}: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        except Exception as exc:  # a bug: keep it to one line unless asked
            if args.debug:
                raise
            print(
                f"patternshop {args.command}: internal error: {type(exc).__name__}: {_one_line(exc)} "
                "(rerun with --debug for the traceback)",
                file=sys.stderr,
            )
            return EXIT_BUG


def entry_point() -> None:
    """Console-script entry: exit with :func:`main`'s status.

    The command's work is done and its files are closed when :func:`main` returns; what is left is the
    interpreter's shutdown, whose final garbage collection walks every object numba and scipy made (0.3-0.4 s
    of a ``synthesize`` on the busy 2-core machine, ``bench/bench_speed.py`` start-up section). ``gc.freeze()``
    leaves them to the operating system; exit handlers and the flushing of stdout and stderr still run.
    """
    status = main()
    gc.freeze()
    sys.exit(status)


if __name__ == "__main__":
    entry_point()
