# SPDX-License-Identifier: Apache-2.0
"""A campaign's generated text in a Markdown document: between its two marker comments."""
from __future__ import annotations

from pathlib import Path


def write_between_markers(path: Path, text: str, begin: str, end: str) -> None:
    """Put `text` between the lines `begin` and `end` of the Markdown file at `path` (appended when they are absent)."""
    path = Path(path)
    doc = path.read_text()
    block = f"{begin}\n{text.rstrip()}\n{end}"
    if begin in doc and end in doc:
        head, rest = doc.split(begin, 1)
        doc = head + block + rest.split(end, 1)[1]
    else:
        doc = doc.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(doc)
