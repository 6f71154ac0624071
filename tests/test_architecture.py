"""The packages import each other in one direction only (docs/architecture.md): a lower layer never imports a higher one.

Layers, lowest first: ``synthesis`` < ``data_gen`` < ``export`` < ``patternshop_nn`` < ``patternshop``.
Every ``import`` and ``from ... import`` statement of every module is read with :mod:`ast`, those inside
functions included (a lazy import is still a dependency).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("synthesis", "data_gen", "export", "patternshop_nn", "patternshop")


def imported_packages(path: Path) -> set[tuple[str, int]]:
    """(top-level package, line) of every absolute import in the file at ``path``."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found |= {(alias.name.split(".")[0], node.lineno) for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add((node.module.split(".")[0], node.lineno))
    return found


def upward_imports(root: Path) -> list[str]:
    """``file:line imports higher`` for each import of a higher layer by a lower one under ``root``."""
    rank = {name: level for level, name in enumerate(LAYERS)}
    violations = []
    for package in LAYERS:
        for path in sorted((root / package).rglob("*.py")):
            for imported, line in sorted(imported_packages(path)):
                if rank.get(imported, -1) > rank[package]:
                    violations.append(f"{path.relative_to(root)}:{line} imports {imported}")
    return violations


def test_no_package_imports_a_higher_layer():
    assert upward_imports(ROOT) == []


def test_checker_finds_an_upward_import(tmp_path):
    for package in LAYERS:
        (tmp_path / package).mkdir()
    (tmp_path / "synthesis" / "bad.py").write_text("def f():\n    from export.runtime import OnnxModel\n")
    (tmp_path / "export" / "fine.py").write_text("import synthesis.labmap\nfrom . import runtime\n")
    assert upward_imports(tmp_path) == ["synthesis/bad.py:2 imports export"]


@pytest.mark.parametrize("package", LAYERS)
def test_every_layer_exists(package):
    assert (ROOT / package / "__init__.py").is_file()
