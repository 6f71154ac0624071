"""The README and docs/ stay true to the tree: length, named tests and benches, links, module list, presets.

Every claim in README.md names the test or bench that checks it, as ``tests/FILE.py::test_name`` or
``bench/FILE``; these tests make sure each name still exists. Text only: nothing is imported or run.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
PACKAGES = ("synthesis", "data_gen", "export", "patternshop_nn", "patternshop")
MAX_README_LINES = 350

TEST_REFERENCE = re.compile(r"(?<![\w/.])(tests/[\w/]+\.py)(?:::(\w+))?")
BENCH_REFERENCE = re.compile(r"(?<![\w/.])(bench/[\w./*-]*\w)")  # a * is a glob
LINK = re.compile(r"\]\(([^)\s]+)\)|<img [^>]*src=\"([^\"]+)\"")


def documents() -> list[Path]:
    return [README, *sorted(DOCS.glob("*.md"))]


def slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """The anchors of a Markdown file's headings (lines in fenced code blocks are no headings)."""
    found, fenced = set(), False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif line.startswith("#") and not fenced:
            found.add(slug(line.lstrip("#")))
    return found


def test_readme_is_at_most_350_lines():
    lines = len(README.read_text().splitlines())
    assert lines <= MAX_README_LINES, f"README.md has {lines} lines; move detail into docs/"


@pytest.mark.parametrize("document", documents(), ids=lambda path: path.name)
def test_named_tests_and_benches_exist(document: Path):
    text = document.read_text()
    missing = []
    for match in TEST_REFERENCE.finditer(text):
        path, name = ROOT / match.group(1), match.group(2)
        if not path.is_file():
            missing.append(match.group(0))
        elif name and not re.search(rf"^\s*(?:async\s+)?def {name}\(", path.read_text(), re.MULTILINE):
            missing.append(match.group(0))
    for match in BENCH_REFERENCE.finditer(text):
        if not ((ROOT / match.group(1)).exists() or "*" in match.group(1) and any(ROOT.glob(match.group(1)))):
            missing.append(match.group(0))
    assert missing == [], f"{document.name} names tests or benches that do not exist"


@pytest.mark.parametrize("document", documents(), ids=lambda path: path.name)
def test_relative_links_resolve(document: Path):
    broken = []
    for match in LINK.finditer(document.read_text()):
        target = match.group(1) or match.group(2)
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        path = (document.parent / file_part).resolve() if file_part else document
        if not path.exists():
            broken.append(target)
        elif anchor and path.suffix == ".md" and anchor not in anchors(path):
            broken.append(target)
    assert broken == [], f"{document.name} has broken links"


def test_architecture_names_every_module():
    text = (DOCS / "architecture.md").read_text()
    modules = sorted(path.relative_to(ROOT).as_posix() for package in PACKAGES for path in (ROOT / package).rglob("*.py"))
    assert modules, "no modules found"
    assert [module for module in modules if module not in text] == []


def test_readme_presets_are_the_shipped_palettes():
    """The README's preset table (a, b, hue, chroma) is the shipped palette's, rounded."""
    presets = json.loads((ROOT / "synthesis" / "assets" / "palette.json").read_text())["presets"]
    rows = {}
    for line in README.read_text().replace("\u2212", "-").splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[0] in presets:
            rows[cells[0]] = cells
    assert set(rows) == set(presets)
    for name, (_, _, ab, hue_chroma) in rows.items():
        want = presets[name]
        assert [float(value) for value in ab.split(",")] == [round(want["a"]), round(want["b"])], name
        hue, chroma = (value.strip().rstrip("°") for value in hue_chroma.split(","))
        assert float(chroma) == round(want["chroma"]), name
        assert hue == "–" if want["chroma"] == 0 else float(hue) == round(want["hue"]), name
