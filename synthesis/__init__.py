"""Patternshop's synthesis library: maps, points, palette, edge-aware PCF, synthesis.

A plain library (numpy, scipy, torch); it never imports Lightning. The public
names below are imported lazily (PEP 562) so that light users, such as
``patternshop --version``, do not pay for colour-science and friends.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "MapFormatError": "synthesis.errors",
    "PatternshopError": "synthesis.errors",
    "PatternshopWarning": "synthesis.errors",
    "PointFileError": "synthesis.errors",
    "LabMap": "synthesis.labmap",
    "read_map": "synthesis.mapio",
    "write_channels": "synthesis.mapio",
    "write_map": "synthesis.mapio",
    "write_preview": "synthesis.mapio",
    "write_tiff": "synthesis.mapio",
    "PointSet": "synthesis.points",
    "read_points": "synthesis.points",
    "write_points": "synthesis.points",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'synthesis' has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
