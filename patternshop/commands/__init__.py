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
