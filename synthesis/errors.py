"""Errors and warnings that users of Patternshop can meet.

The CLI prints a :class:`PatternshopError` as one line on stderr and exits with
status 2; anything else is a bug and gets a traceback only with ``--debug``.
"""

from __future__ import annotations


class PatternshopError(Exception):
    """A problem with the user's input (file, argument, data), not a bug."""


class MapFormatError(PatternshopError):
    """A map file cannot be read or written in the requested form."""


class PointFileError(PatternshopError):
    """A point file is malformed; the message names the file and line."""


class PatternshopWarning(UserWarning):
    """Something worked, but the user should know about a loss or a guess."""
