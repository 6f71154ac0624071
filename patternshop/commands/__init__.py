"""Subcommands of the ``patternshop`` command, one module per topic, plus shared helpers."""

from __future__ import annotations

from pathlib import Path

from synthesis.errors import PatternshopError


def check_output(output: str | Path, *inputs: str | Path, suffixes: tuple[str, ...] = ()) -> Path:
    """Validate an output path before any work: right suffix, not one of the inputs.

    Raises:
        PatternshopError: the suffix is wrong or the output would overwrite an input.
    """
    output = Path(output)
    if suffixes and output.suffix.lower() not in suffixes:
        raise PatternshopError(f"{output}: output must end in {' or '.join(suffixes)}")
    for source in inputs:
        if Path(source).resolve() == output.resolve():
            raise PatternshopError(f"{output}: output would overwrite the input")
    return output


def check_map_output(output: str | Path, *inputs: str | Path) -> Path:
    """Validate a map output before any work: a CIELAB ``.tif``/``.tiff`` or channel PNGs ``NAME.L.png``, not an input.

    Raises:
        PatternshopError: another suffix, or an output that would overwrite an input.
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
