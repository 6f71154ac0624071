"""Patternshop: edit point patterns as CIELAB images. `import patternshop` gives the Python API (:mod:`patternshop.api`); the ``patternshop`` command (:mod:`patternshop.cli`) calls the same functions."""

from typing import TYPE_CHECKING, Any

from patternshop import api as _api  # light: its names load their modules on first use (PEP 562)

if TYPE_CHECKING:
    from patternshop.api import *  # noqa: F403 - the names below, for type checkers and editors

    __version__: str

__all__ = list(_api.__all__)  # the Python API: see patternshop.api


def __getattr__(name: str) -> Any:
    if name == "__version__":  # looked up on first use: importlib.metadata is a fifth of `import patternshop`
        from synthesis.version import package_version

        globals()["__version__"] = version = package_version()
        return version
    if name in _api.__all__:
        return getattr(_api, name)
    raise AttributeError(f"module 'patternshop' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__) | {"__version__"})
