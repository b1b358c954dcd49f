"""The documents point at things that exist: every relative link in README.md, BENCHMARKS.md and the lab notes
opens a file, and every benchmark script the README tells a user to run is in benchmarks/."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", ROOT / "BENCHMARKS.md", *sorted((ROOT / "docs" / "lab-notes").glob("*.md"))]
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def broken_links(path: Path) -> list[str]:
    """The relative link targets in a markdown file that do not exist beside it."""
    targets = LINK.findall(path.read_text(encoding="utf-8"))
    return [t for t in targets if "://" not in t and not (path.parent / t).exists()]


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_open_a_file(path):
    assert path.is_file()
    assert not broken_links(path), f"{path.name} links to missing files: {broken_links(path)}"


def test_readme_names_only_scripts_that_exist():
    named = set(re.findall(r"benchmarks/(\w+\.py)", (ROOT / "README.md").read_text(encoding="utf-8")))
    assert named, "the README names no benchmark script"
    assert {n for n in named if not (ROOT / "benchmarks" / n).is_file()} == set()


def test_the_link_check_finds_a_missing_file(tmp_path):
    (tmp_path / "there.md").write_text("x")
    (tmp_path / "doc.md").write_text("[a](there.md) [b](gone.md#part) [c](https://example.org/x.md)")
    assert broken_links(tmp_path / "doc.md") == ["gone.md"]
