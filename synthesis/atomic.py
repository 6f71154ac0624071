"""Atomic file writes: write to a temporary file beside the target, then rename.

A failure (exception, interrupt) never leaves a half-written output behind, and
an existing file is only replaced once the new one is complete. Inside
:func:`all_or_nothing`, the renames of every atomic write wait for the end of
the block, so that a command's outputs (points, PNG, SVG, report) are replaced
together or not at all.

Temporary files are named ``.NAME.PID.RANDOM.tmpSUFFIX`` beside ``NAME``; one
whose process has died (killed with ``kill -9``) is removed by the next write
into its folder (:func:`remove_stale_temporaries`).
"""

from __future__ import annotations

import contextlib
import contextvars
import glob
import os
import re
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

_TEMPORARY_NAME = re.compile(r"^\.(?P<target>.+)\.(?P<pid>\d+)\.[A-Za-z0-9_]+\.tmp(\.[^.]*)?$")
# (temporary, target) renames waiting for the end of the innermost all_or_nothing block; None outside one
_PENDING_RENAMES: contextvars.ContextVar[list[tuple[Path, Path]] | None] = contextvars.ContextVar("pending_renames", default=None)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_DEFAULT_MODE = 0o666 & ~_umask()


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def remove_stale_temporaries(folder: str | os.PathLike, target_name: str | None = None) -> list[Path]:
    """Remove the temporary files of dead processes in ``folder`` (only those of ``target_name`` if given).

    Returns the removed paths. Files of running processes, and files not named
    like our temporaries, are left alone.
    """
    removed = []
    pattern = f".{glob.escape(target_name)}.*.tmp*" if target_name is not None else ".*.tmp*"
    for path in Path(folder).glob(pattern):
        match = _TEMPORARY_NAME.match(path.name)
        if match is None or (target_name is not None and match["target"] != target_name) or _process_alive(int(match["pid"])):
            continue
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
            removed.append(path)
    return removed


@contextlib.contextmanager
def all_or_nothing() -> Iterator[None]:
    """Replace the targets of all atomic writes inside the block together at its end, or none on an exception.

    Nested blocks join the outermost one.
    """
    if _PENDING_RENAMES.get() is not None:
        yield
        return
    pending: list[tuple[Path, Path]] = []
    token = _PENDING_RENAMES.set(pending)
    try:
        yield
        while pending:
            tmp, path = pending[0]
            os.replace(tmp, path)
            pending.pop(0)
    finally:
        _PENDING_RENAMES.reset(token)
        for tmp, _ in pending:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()


@contextlib.contextmanager
def atomic_paths(targets: Sequence[str | os.PathLike]) -> Iterator[list[Path]]:
    """Yield temporary paths to write; rename them onto ``targets`` on success.

    The temporary files live in the targets' folders (so the rename stays on one
    file system) and keep each target's suffix (so writers that look at the
    extension pick the right format). On an exception they are removed and no
    target is touched. Several targets are renamed one after the other once all
    of them were written; inside :func:`all_or_nothing`, at the end of that block.
    """
    final = [Path(t) for t in targets]
    temporary: list[Path] = []
    handed_over = False
    try:
        for path in final:
            if not path.parent.is_dir():
                raise FileNotFoundError(f"{path}: folder {path.parent} does not exist")
            remove_stale_temporaries(path.parent, path.name)
            handle, name = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp" + path.suffix, dir=path.parent)
            os.close(handle)
            os.chmod(name, _DEFAULT_MODE)  # mkstemp makes 0600; outputs are ordinary files
            temporary.append(Path(name))
        yield temporary
        pending = _PENDING_RENAMES.get()
        if pending is not None:
            pending.extend(zip(temporary, final))
            handed_over = True
        else:
            for tmp, path in zip(temporary, final):
                os.replace(tmp, path)
    finally:
        if not handed_over:
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
