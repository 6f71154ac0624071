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

_ROOT = Path(__file__).resolve().parent.parent
#: The Hydra configs: ``conf/`` in a checkout (and an editable install), ``patternshop/conf`` in an installed wheel.
CONF_DIR = _ROOT / "conf" if (_ROOT / "conf" / "pairs.yaml").is_file() else _ROOT / "patternshop" / "conf"


def git_commit() -> str:
    """HEAD of the checkout the code runs from, or ``"unknown"``."""
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True, cwd=_ROOT).stdout.strip()
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


def run_config_command(prog: str, default_name: str, doc: str, task, argv: list[str] | None = None) -> int:  # noqa: ANN001
    """Shared ``main`` of the Hydra-configured build commands (``python -m data_gen.X key=value ...``).

    ``--help`` prints ``doc`` and the composed default config; ``--debug`` shows
    tracebacks; otherwise a user error (bad override, missing dataset, I/O) is one
    line ``PROG: error: ...`` on stderr and exit status 2. ``task(cfg)`` returns
    what to print as JSON.
    """
    import json

    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    from synthesis.errors import PatternshopError

    args = list(sys.argv[1:] if argv is None else argv)
    if "--help" in args or "-h" in args:
        print(f"usage: {prog} [--config-name NAME] [--debug] [key=value ...]\n\n{doc.strip()}\n\n"
              f"Settings (conf/{default_name}.yaml; override any as key=value):\n")
        print(OmegaConf.to_yaml(compose_config(default_name, [])))
        return 0
    debug = "--debug" in args
    args = [a for a in args if a != "--debug"]
    try:
        result = task(compose_config(default_name, args))
    except (PatternshopError, OSError, HydraException, OmegaConfBaseException) as exc:
        if debug:
            raise
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        print(f"{prog}: error: {message}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2))
    return 0
