# SPDX-License-Identifier: Apache-2.0
"""bench/compare_residuals.py: each image's RMS residual over the stars both runs match."""
from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import compare_residuals  # noqa: E402


def _run(path: Path, residuals: dict[str, dict[str, float]]) -> str:
    doc = {"images": [{"id": image, "solvers": {"ours": {"residual_arcsec_by_hip": by_hip}}}
                      for image, by_hip in residuals.items()]}
    path.write_text(json.dumps(doc))
    return str(path)


def test_only_the_stars_both_runs_match_are_compared(tmp_path, capsys):
    a = _run(tmp_path / "a.json", {"img": {"1": 3.0, "2": 4.0, "3": 100.0}, "same": {"5": 1.0}})
    b = _run(tmp_path / "b.json", {"img": {"1": 0.0, "2": 5.0}, "same": {"5": 1.0}})
    assert compare_residuals.main([a, b]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| img ")]
    # Stars 1 and 2 only: sqrt((9 + 16) / 2) = 3.54 against sqrt((0 + 25) / 2) = 3.54 -> equal, not printed.
    assert rows == []
    c = _run(tmp_path / "c.json", {"img": {"1": 1.0, "2": 1.0}, "same": {"5": 1.0}})
    assert compare_residuals.main([a, c]) == 0
    out = capsys.readouterr().out
    assert "| img | 2 | 3.54 | 1.00 |" in out and "| same |" not in out
