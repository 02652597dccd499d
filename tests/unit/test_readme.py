"""The README stays a five-minute read whose links all land, and every command it shows exists.

The user guide itself (docs/, mkdocs.yml) is checked by MkDocs in strict mode (scripts/test,
phase "docs"); the README is outside MkDocs' docs folder, so its links are checked here.
"""

from __future__ import annotations

import re
from pathlib import Path

from markdown.extensions.toc import slugify

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _anchors(page: Path) -> set[str]:
    """The heading anchors MkDocs gives a page (its toc extension's slugify)."""
    found = set()
    fenced = False
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and re.match(r"#{1,6} ", line):
            title = re.sub(r"[`*]", "", line.lstrip("#").strip())
            found.add(slugify(title, "-"))
    return found


def test_readme_is_short():
    lines = README.read_text(encoding="utf-8").count("\n")
    assert lines <= 250, f"README.md has {lines} lines: the manual belongs in docs/ (at most 250)"


def test_every_readme_link_resolves():
    text = README.read_text(encoding="utf-8")
    links = [t for t in LINK.findall(text) if "://" not in t]
    assert links, "the README links into the user guide"
    for target in links:
        path, _, anchor = target.partition("#")
        page = (ROOT / path).resolve()
        assert page.exists(), f"README.md links to {target}, which does not exist"
        if anchor:
            assert anchor in _anchors(page), f"README.md links to {target}: no such heading"

