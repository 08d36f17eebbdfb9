# SPDX-License-Identifier: Apache-2.0
"""
The PSF-width sensitivity benchmark (bench/bench_psf_sensitivity.py): what counts as a cliff, its report.

The corpus itself is solved by the benchmark (`make bench`); a real frame it found a cliff on
is a test of its own (test/centroid/test_undetermined_blend_fit.py, test/identify/test_scale_free.py).
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_psf_sensitivity as bench  # noqa: E402


def _result(solved=True, stars=140, boresight=8.0):
    return {"solved": solved, "stars": stars, "boresight_arcsec": boresight if solved else None}


def test_a_cliff_is_a_lost_solve_a_lost_fifth_of_the_stars_or_a_lost_arcminute():
    default = _result()
    assert not bench.cliff(default, _result(stars=113))
    assert bench.cliff(default, _result(stars=111))  # < 80 % of 140
    assert bench.cliff(default, _result(solved=False))
    assert bench.cliff(default, _result(boresight=61.0))
    assert not bench.cliff(_result(boresight=90.0), _result(boresight=95.0))  # the default missed 1' already
    assert not bench.cliff(_result(solved=False, stars=0), _result(solved=False, stars=0))
    assert not bench.cliff(_result(boresight=None), _result(boresight=None))  # no reference: stars only


def test_report_marks_the_cliffs_and_counts_them():
    rows = [{"id": "good", "default": dict(_result(), sigma_px=0.7),
             "widths": [dict(_result(stars=139), factor=f, cliff=False) for f in bench.FACTORS]},
            {"id": "fragile", "default": dict(_result(), sigma_px=0.65),
             "widths": [dict(_result(solved=False, stars=0), factor=f, cliff=True) if f < 1 else
                        dict(_result(), factor=f, cliff=False) for f in bench.FACTORS]},
            {"id": "unsolved", "default": {"solved": False, "stars": 0, "boresight_arcsec": None}, "widths": []}]
    meta = {"command": "python -m bench.bench_psf_sensitivity", "date": "today", "elapsed_s": 1.0, "cpu": "cpu",
            "cores": 2, "python": "3.11"}
    text = bench.render_markdown(rows, meta)
    assert text.startswith(bench.HEADER)
    assert "| fragile | 0.65 | 140 / 8″ | **not solved** | **not solved** | **not solved** | 140 / 8″ |" in text
    assert "2 of 3 images solved at defaults; 3 cliffs in 12 fixed-width solves: fragile at σ × 0.85" in text
