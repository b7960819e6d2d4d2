"""Issue 12 item 16: the documents resolve in a clone. Every relative link of the README and
of docs/ points at a file of the repository, and every contract the documents cite by its
shared name (``spec/reports.md`` ...) is a copy in docs/spec/ that the citation links to."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
CONTRACTS = ("wire-protocol.md", "certificate.md", "sample-log.md", "reports.md")


def _prose(text: str) -> str:
    """The text outside fenced code blocks (a shell comment there is not a citation)."""
    return re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(doc: Path) -> None:
    broken = []
    for target in LINK.findall(_prose(doc.read_text(encoding="utf-8"))):
        if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # a URL or an anchor in the same page
        path = (doc.parent / target.split("#", 1)[0]).resolve()
        if not path.exists():
            broken.append(target)
    assert not broken, f"{doc.relative_to(ROOT)}: links to missing files: {broken}"


def test_the_contracts_are_in_the_clone() -> None:
    for name in CONTRACTS:
        copy = ROOT / "docs" / "spec" / name
        assert copy.is_file(), f"docs/spec/{name} is missing"
        assert copy.read_text(encoding="utf-8").startswith("# "), copy


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_cited_contract_is_a_link(doc: Path) -> None:
    """A citation ``spec/NAME.md`` in prose is the text of a link to the copy."""
    text = _prose(doc.read_text(encoding="utf-8"))
    bare = []
    for m in re.finditer(r"spec/([a-z-]+\.md)", text):
        before = text[max(0, m.start() - 8) : m.start()]
        linked = text[m.end() : m.end() + 2] == "](" or before.endswith(("](", "](docs/"))
        if m.group(1) in CONTRACTS and not linked and doc.parent.name != "spec":
            bare.append(m.group(0))
    assert not bare, f"{doc.relative_to(ROOT)} cites contracts without a link: {bare}"
