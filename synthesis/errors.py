"""Errors and warnings that users of Patternshop can meet.

The CLI prints a :class:`PatternshopError` as one line on stderr and exits with
status 2; anything else is a bug and gets a traceback only with ``--debug``. The
``python -m`` tools (training, data, evaluation) share that rule through
:func:`run_module_cli`.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path


class PatternshopError(Exception):
    """A problem with the user's input (file, argument, data), not a bug."""


class MapFormatError(PatternshopError):
    """A map file cannot be read or written in the requested form."""


class PointFileError(PatternshopError):
    """A point file is malformed; the message names the file and line."""


class PatternshopWarning(UserWarning):
    """Something worked, but the user should know about a loss or a guess."""


def require_file(path: str | os.PathLike, what: str, error: type[PatternshopError] = PatternshopError,
                 missing: str = "no such file") -> Path:
    """``path`` as a Path if it names a file; else ``error``: "PATH: is a folder, not WHAT" or "PATH: MISSING".

    ``what`` names the file expected, with its article: "an image file", "a point file".
    """
    path = Path(path)
    if path.is_dir():
        raise error(f"{path}: is a folder, not {what}")
    if not path.is_file():
        raise error(f"{path}: {missing}")
    return path


def run_module_cli(parser: argparse.ArgumentParser, body: Callable[[argparse.Namespace], int | None],
                   argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` (with a ``--debug`` flag added to ``parser`` and its subcommands) and run ``body(args)``; return the exit status.

    A :class:`PatternshopError` or ``OSError`` from ``body`` becomes one line on stderr, "PROG: error: MESSAGE"
    (the message's whitespace collapsed), and status 2; with ``--debug`` it is raised with its traceback. ``body``
    returns its status, ``None`` meaning 0. Argument errors stay argparse's (usage and status 2).
    """
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    for action in parser._actions:  # and after a subcommand's arguments, without overriding one given before it
        if isinstance(action, argparse._SubParsersAction):
            for subparser in action.choices.values():
                subparser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                                       help="show tracebacks on errors")
    args = parser.parse_args(argv)
    try:
        status = body(args)
    except (PatternshopError, OSError) as exc:
        if args.debug:
            raise
        print(f"{parser.prog}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    return 0 if status is None else status
