"""Errors and warnings that users of Patternshop can meet.

The CLI prints a :class:`PatternshopError` as one line on stderr and exits with
status 2; anything else is a bug and gets a traceback only with ``--debug``.
"""

from __future__ import annotations

import os
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
