"""Folders anywhere fsspec reaches: a local path, ``file://``, ``memory://``, or ``s3://``/``gs://`` with the user's
s3fs/gcsfs installed (through universal_pathlib's pathlib API).

Pair folders (:mod:`data_gen.shards`, :mod:`data_gen.pairs`) and the corpus cache (:mod:`data_gen.corpus`)
use these, so ``out_dir`` and ``cache_dir`` may be URLs. Writes are atomic: locally (``file://`` too) a
temporary file renamed onto the target (:mod:`synthesis.atomic`); elsewhere the whole object is uploaded
in one request (an object store replaces an object at once, never partly).
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

from upath import UPath

from synthesis.atomic import atomic_path

LOCAL_PROTOCOLS = ("", "file", "local")
StoragePath = Path | UPath  # what as_path returns


def as_path(location: str | os.PathLike) -> StoragePath:
    """A local location (a path or a ``file://`` URL) as a :class:`pathlib.Path`, any other URL as a :class:`UPath`."""
    if isinstance(location, Path) and not isinstance(location, UPath):
        return location
    path = location if isinstance(location, UPath) else UPath(location)
    return Path(path.path) if path.protocol in LOCAL_PROTOCOLS else path


def is_local(path: StoragePath) -> bool:
    """Whether ``path`` (from :func:`as_path`) is on this machine's file system."""
    return not isinstance(path, UPath) or path.protocol in LOCAL_PROTOCOLS


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
