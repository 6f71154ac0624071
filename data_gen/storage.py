"""Folders anywhere fsspec reaches: a local path, ``file://``, ``memory://``, or ``s3://``/``gs://`` with the user's
s3fs/gcsfs installed (through universal_pathlib's pathlib API).

Pair folders (:mod:`data_gen.shards`, :mod:`data_gen.pairs`) and the corpus cache (:mod:`data_gen.corpus`)
use these, so ``out_dir`` and ``cache_dir`` may be URLs. Writes are atomic: locally (``file://`` too) a
temporary file renamed onto the target (:mod:`synthesis.atomic`); elsewhere the whole object is uploaded
in one request (an object store replaces an object at once, never partly).

Code that reads and writes local paths only (the point and map readers and writers) reaches URLs through
:func:`local_copies` (remote inputs downloaded into a temporary folder) and :func:`local_target` (an output
written locally, then uploaded with :func:`write_atomic`); local paths go through both unchanged, at no cost.
universal_pathlib (with fsspec, 40 ms to import) is imported only for text that may be a URL (:data:`MAYBE_URL`):
a local ``convert`` does not import it in its calling process nor in its workers.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, Union

from synthesis.atomic import atomic_path

if TYPE_CHECKING:
    from upath import UPath

LOCAL_PROTOCOLS = ("", "file", "local")
StoragePath = Union[Path, "UPath"]  # what as_path returns
# what universal_pathlib may read as a URL: a scheme of two or more characters and a slash, or a chain (a::b); any
# other text is a local path to it as well, so it becomes a Path without importing it (fsspec's 40 ms at start-up)
MAYBE_URL = re.compile(r"[A-Za-z][A-Za-z0-9+.-]+:/|.*::")


def _is_upath(path: object) -> bool:
    """Whether ``path`` is a :class:`UPath` (none is before :func:`as_path` has imported universal_pathlib)."""
    upath = sys.modules.get("upath")
    return upath is not None and isinstance(path, upath.UPath)


def as_path(location: str | os.PathLike) -> StoragePath:
    """A local location (a path or a ``file://`` URL) as a :class:`pathlib.Path`, any other URL as a :class:`UPath`."""
    if not _is_upath(location) and (isinstance(location, Path) or not MAYBE_URL.match(os.fspath(location))):
        return location if isinstance(location, Path) else Path(location)
    from upath import UPath

    path = location if isinstance(location, UPath) else UPath(location)
    return Path(path.path) if path.protocol in LOCAL_PROTOCOLS else path


def is_local(path: StoragePath) -> bool:
    """Whether ``path`` (from :func:`as_path`) is on this machine's file system."""
    return not _is_upath(path) or path.protocol in LOCAL_PROTOCOLS


def write_atomic(target: str | os.PathLike, write: Callable[[BinaryIO], None]) -> None:
    """Write ``target`` with ``write(handle)``, atomically (see the module docstring)."""
    target = as_path(target)
    if is_local(target):
        with atomic_path(target) as tmp, open(tmp, "wb") as handle:
            write(handle)
        return
    buffer = io.BytesIO()
    write(buffer)
    target.fs.pipe_file(target.path, buffer.getvalue())


def write_text_atomic(target: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``target`` atomically."""
    write_atomic(target, lambda handle: handle.write(text.encode("utf-8")))


@dataclass(frozen=True)
class LocalCopies:
    """What :func:`local_copies` yields: ``paths``, local files holding the inputs, and ``folders``, each local
    folder's text and the remote folder's it stands for."""

    paths: list[Path]
    folders: tuple[tuple[str, str], ...] = ()

    def named(self, text: str) -> str:
        """``text`` (an error message) with each local copy's folder replaced by its URL's."""
        for local, remote in sorted(self.folders, key=lambda pair: -len(pair[0])):  # .../10 before .../1
            text = text.replace(local, remote)
        return text


@contextlib.contextmanager
def local_copies(paths: Sequence[StoragePath]) -> Iterator[LocalCopies]:
    """Local files for readers that take paths: a local path as it is; a URL downloaded into a temporary folder
    (removed afterwards) under its own name, one folder per remote folder, so that siblings stay siblings (channel
    PNGs). A missing input is not downloaded, for the reader to say so."""
    if all(is_local(path) for path in paths):
        yield LocalCopies(list(paths))
        return
    with tempfile.TemporaryDirectory(prefix="patternshop-") as scratch:
        folders: dict[str, Path] = {}
        copies = []
        for path in paths:
            if is_local(path):
                copies.append(path)
                continue
            folder = folders.setdefault(str(path.parent), Path(scratch) / str(len(folders)))
            folder.mkdir(exist_ok=True)
            copies.append(folder / path.name)
            if path.is_file():
                path.fs.get_file(path.path, str(copies[-1]))
        yield LocalCopies(copies, tuple((str(local), remote) for remote, local in folders.items()))


@contextlib.contextmanager
def local_target(target: str | os.PathLike | UPath) -> Iterator[Path]:
    """A local path to write ``target`` through: ``target`` itself when local (the writer's own atomic rename);
    else a temporary file, uploaded onto ``target`` in one request (:func:`write_atomic`) once the block ends
    without an exception."""
    target = as_path(target)
    if is_local(target):
        yield target
        return
    with tempfile.TemporaryDirectory(prefix="patternshop-") as scratch:
        local = Path(scratch) / target.name
        yield local
        write_atomic(target, lambda handle: handle.write(local.read_bytes()))


def in_process(path: StoragePath) -> bool:
    """Whether ``path``'s file system lives in this process only (``memory://``): other processes see it empty."""
    return _is_upath(path) and path.protocol == "memory"
