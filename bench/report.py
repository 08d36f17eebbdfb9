# SPDX-License-Identifier: Apache-2.0
"""What every benchmark shares when it writes docs/BENCHMARKS.md."""
from __future__ import annotations

from pathlib import Path


def write_section(path: Path, text: str, header: str | None = None) -> None:
    """
    Replace the `## ...` section of the Markdown file at `path` whose header line equals `header`.

    `header` defaults to the first line of `text`; the section runs up to the next `## ` line; it
    is appended when absent. The rest of the file is kept.
    """
    header = (header or text.lstrip().splitlines()[0]).rstrip()
    path = Path(path)
    lines = path.read_text().splitlines(keepends=True) if path.exists() else ["# Benchmarks\n"]
    body = text.rstrip("\n") + "\n"
    start = next((i for i, line in enumerate(lines) if line.rstrip() == header), None)
    if start is None:
        new = "".join(lines).rstrip("\n") + "\n\n" + body
    else:
        end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
        tail = "".join(lines[end:])
        new = "".join(lines[:start]) + body + ("\n" + tail if tail else "")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(new)
