# SPDX-License-Identifier: Apache-2.0
"""
Every relative link of the documents leads somewhere: the file exists, and a #anchor names one of its headings.

README.md, docs/*.md and msg_docs/*.md; anchors as GitHub makes them from headings (lowercase,
punctuation dropped, spaces to hyphens). A benchmark that renames its section, or a document
that drops one, fails here until the links follow.
"""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def documents() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "msg_docs").glob("*.md"))]


def anchor(heading: str) -> str:
    """Return the anchor GitHub makes of a Markdown heading's text."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    found, seen = set(), {}
    in_code = False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            in_code = not in_code
        if in_code or not line.startswith("#"):
            continue
        base = anchor(line.lstrip("#"))
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(base if count == 0 else f"{base}-{count}")
    return found


def broken_links(path: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    broken = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        file_part, _, fragment = target.partition("#")
        linked = (path.parent / file_part).resolve() if file_part else path
        if not linked.exists():
            broken.append(f"{target}: no such file")
        elif fragment and linked.suffix == ".md" and fragment not in anchors(linked):
            broken.append(f"{target}: no such heading in {linked.name}")
    return broken


def test_anchor_follows_githubs_rule():
    assert anchor(" Real images, field hint +3 % off") == "real-images-field-hint-3--off"
    assert anchor(" 6. Known limits") == "6-known-limits"
    assert anchor(" `star-tracker solve`: an image") == "star-tracker-solve-an-image"


def test_every_relative_link_of_the_documents_resolves():
    broken = {str(path.relative_to(ROOT)): links for path in documents() if (links := broken_links(path))}
    assert broken == {}
