"""The user-facing docs: README and docs/ link only to files that exist and name no path outside the repository."""

from __future__ import annotations

import functools
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", ROOT / "pass3d_ros" / "weights" / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(doc: Path) -> None:
    targets = [t for t in LINK.findall(doc.read_text()) if "://" not in t]
    missing = [t for t in targets if not (doc.parent / t).exists()]
    assert not missing, f"{doc.name} links to missing files: {missing}"


ANCHOR_LINK = re.compile(r"\]\(([^)#\s]*)#([^)\s]+)\)")


@functools.cache
def _anchors(doc: Path) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation but hyphens dropped, spaces to hyphens."""
    headings = re.findall(r"^#+ (.*)$", doc.read_text(), re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in headings}


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_section_links_name_a_heading(doc: Path) -> None:
    broken = []
    for path, anchor in ANCHOR_LINK.findall(doc.read_text()):
        target = (doc.parent / path) if path else doc
        if "://" not in path and target.suffix == ".md" and target.exists() and anchor not in _anchors(target):
            broken.append(f"{path}#{anchor}")
    assert not broken, f"{doc.name} links to missing sections: {broken}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_paths_outside_the_repository(doc: Path) -> None:
    text = doc.read_text()
    assert "../shared" not in text, f"{doc.name} names a path users do not have"
    if "experiments" not in doc.parts:  # the experiment logs record where their runs read from
        assert "/work/" not in text, f"{doc.name} names a path of the development machine"


def test_readme_is_a_short_guide_with_the_launch_line_early() -> None:
    text = (ROOT / "README.md").read_text()
    assert len(text) <= 8000
    half = text[: len(text) // 2]
    assert "ros2 launch pass3d_ros pass3d.launch.py" in half
    assert "`/pass3d/labeled`" in half and "`/pass3d/proposals`" in half


def test_model_card_is_short() -> None:
    assert len((ROOT / "pass3d_ros" / "weights" / "README.md").read_text()) <= 4000
