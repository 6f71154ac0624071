"""Provenance shared by the build commands: commit, library versions, machine, Hydra config loading."""

from __future__ import annotations

import hashlib
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

CONF_DIR = Path(__file__).resolve().parent.parent / "conf"


def git_commit() -> str:
    """HEAD of the checkout the code runs from, or ``"unknown"``."""
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True, cwd=CONF_DIR).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def versions() -> dict:
    import finufft
    import sklearn
    import torch

    return {"python": platform.python_version(), "numpy": np.__version__, "torch": torch.__version__,
            "finufft": getattr(finufft, "__version__", "unknown"), "scikit-learn": sklearn.__version__}


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores"


def utc_now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def file_sha256(path: str | os.PathLike) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def compose_config(default_name: str, argv: list[str] | None = None):  # noqa: ANN201 - omegaconf.DictConfig
    """Hydra config ``default_name`` (``--config-name NAME`` picks another) with ``key=value`` overrides from argv."""
    from hydra import compose, initialize_config_dir

    args = list(sys.argv[1:] if argv is None else argv)
    name = default_name
    if "--config-name" in args:
        at = args.index("--config-name")
        name = args[at + 1]
        del args[at : at + 2]
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        return compose(config_name=name, overrides=args)
