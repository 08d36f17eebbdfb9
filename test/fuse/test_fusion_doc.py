# SPDX-License-Identifier: Apache-2.0
"""docs/FUSION.md: its Python example runs as written and fuses both heads."""
from __future__ import annotations

import re
from pathlib import Path

DOC = Path(__file__).resolve().parents[2] / "docs" / "FUSION.md"


def test_the_example_runs_and_fuses_both_heads(capsys):
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    assert len(blocks) == 1
    exec(compile(blocks[0], str(DOC), "exec"), {"__name__": "fusion_doc_example"})
    printed = capsys.readouterr().out
    assert printed.count("Admission(accepted=True") == 2
    assert "('a', 'b')" in printed and "AlignmentEstimate(correction=" in printed
