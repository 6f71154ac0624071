"""Atomic file writes: write to a temporary file beside the target, then rename.

A failure (exception, interrupt) never leaves a half-written output behind, and
an existing file is only replaced once the new one is complete.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path



def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_DEFAULT_MODE = 0o666 & ~_umask()


@contextlib.contextmanager
def atomic_paths(targets: Sequence[str | os.PathLike]) -> Iterator[list[Path]]:
    """Yield temporary paths to write; rename them onto ``targets`` on success.

    The temporary files live in the targets' folders (so the rename stays on one
    file system) and keep each target's suffix (so writers that look at the
    extension pick the right format). On an exception they are removed and no
    target is touched. Several targets are renamed one after the other once all
    of them were written.
    """
    final = [Path(t) for t in targets]
    temporary: list[Path] = []
    try:
        for path in final:
            if not path.parent.is_dir():
                raise FileNotFoundError(f"{path}: folder {path.parent} does not exist")
            handle, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
            os.close(handle)
            os.chmod(name, _DEFAULT_MODE)  # mkstemp makes 0600; outputs are ordinary files
            temporary.append(Path(name))
        yield temporary
        for tmp, path in zip(temporary, final):
            os.replace(tmp, path)
    finally:
        for tmp in temporary:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike) -> Iterator[Path]:
    """Single-file form of :func:`atomic_paths`."""
    with atomic_paths([target]) as (tmp,):
        yield tmp


def atomic_write_text(target: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``target`` atomically."""
    with atomic_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")
