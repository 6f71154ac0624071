"""The installed package version, for `--version` and file provenance."""

from __future__ import annotations


def package_version() -> str:
    """Version of the installed ``patternshop`` distribution ("unknown" when not installed)."""
    from importlib import metadata  # here, not at import: it takes tens of ms and most imports never ask

    try:
        return metadata.version("patternshop")
    except metadata.PackageNotFoundError:
        return "unknown"


def version_string() -> str:
    """``"patternshop X.Y.Z"``, as written into the files Patternshop makes."""
    return f"patternshop {package_version()}"
