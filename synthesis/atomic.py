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

from synthesis.errors import PatternshopError

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


def _not_writable(target: Path, exc: OSError) -> PatternshopError:
    """The one-line error for a failed write of ``target``, naming it (never a temporary file)."""
    return PatternshopError(f"{target}: cannot write into folder {target.parent} ({exc.strerror or exc})")


def _temporary_beside(target: Path) -> Path:
    """Create an empty temporary file for ``target`` in its folder, named as the module docstring says.

    Raises:
        FileNotFoundError: the folder does not exist.
        PatternshopError: the folder takes no new file (permissions, a read-only file system, a full disk).
    """
    if not target.parent.is_dir():
        raise FileNotFoundError(f"{target}: folder {target.parent} does not exist")
    remove_stale_temporaries(target.parent, target.name)
    try:
        handle, name = tempfile.mkstemp(prefix=f".{target.name}.{os.getpid()}.", suffix=".tmp" + target.suffix, dir=target.parent)
    except OSError as exc:
        raise _not_writable(target, exc) from exc
    os.close(handle)
    os.chmod(name, _DEFAULT_MODE)  # mkstemp makes 0600; outputs are ordinary files
    return Path(name)


def _replace(tmp: Path, target: Path) -> None:
    """Rename a finished temporary file onto its target; an error names the target."""
    try:
        os.replace(tmp, target)
    except OSError as exc:
        raise _not_writable(target, exc) from exc


def check_writable(target: str | os.PathLike) -> Path:
    """Check, before any work, that ``target`` can be written: its folder exists and takes a new file.

    Probed by creating and removing a temporary file beside it, so whatever the
    real write would meet (permissions, ACLs, a read-only file system) is met now.

    Raises:
        FileNotFoundError: the folder does not exist.
        PatternshopError: the folder takes no new file; the message names ``target``.
    """
    path = Path(target)
    _temporary_beside(path).unlink()
    return path


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
            _replace(tmp, path)
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
            temporary.append(_temporary_beside(path))
        try:
            yield temporary
        except OSError as exc:  # a writer's error names the temporary file: name the user's target instead
            targets = {str(tmp): path for tmp, path in zip(temporary, final)}
            if exc.filename is None or str(exc.filename) not in targets:
                raise
            raise _not_writable(targets[str(exc.filename)], exc) from exc
        pending = _PENDING_RENAMES.get()
        if pending is not None:
            pending.extend(zip(temporary, final))
            handed_over = True
        else:
            for tmp, path in zip(temporary, final):
                _replace(tmp, path)
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
