# SPDX-License-Identifier: Apache-2.0
"""
The PSF-range centroiding benchmark (bench/bench_psf_range.py).

Its scoring against known positions, a few of its cases at the centroider's defaults (today's
centroider meets the goals at the sigma it assumes, 1 px), and the quick run's report.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import alt_renderer as alt  # noqa: E402
from bench import bench_psf_range as bench  # noqa: E402
from star_tracker.centroid.spots import Spots  # noqa: E402


def test_scoring_matches_stars_counts_extra_spots_and_skips_stars_next_to_defects():
    x, y = np.array([10.0, 50.0, 90.0, 130.0]), np.array([20.0, 20.0, 20.0, 20.0])
    snr = np.array([50.0, 50.0, 50.0, 5.0])
    # Star 0 found 0.3 px off, star 1 missed (spot 4 px away: beyond 2 sigma + 1 = 3 px), star 2
    # next to a cosmic ray (not scored), star 3 faint and found exactly; one spot far from all.
    spots = Spots.from_xy(np.array([10.3, 54.0, 90.0, 130.0, 200.0]), np.array([20.0, 20.0, 20.0, 20.0, 60.0]),
                          sigma_px=0.1, width=256, height=128)
    scored = bench.Scored()
    scored.add(spots, x, y, snr, np.full(4, 0.01), np.array([92.0]), np.array([21.0]), np.array([4.0]), 1.0, 0.002)
    row = scored.row()
    assert row["stars"] == 3 and row["stars_snr_ge_10"] == 2
    assert row["detected_snr_ge_10"] == 0.5 and row["detection_met"] is False
    assert row["rms_px"] == pytest.approx(0.3) and row["ratio"] == pytest.approx(3.0) and row["ratio_met"] is False
    assert row["extra_spots_per_frame"] == 2  # the far spot and the one 4 px from star 1
    assert row["median_ms"] == pytest.approx(2.0)


@pytest.mark.parametrize("case",
                         [bench.Case("alt", alt.GaussianPsf(1.0)), bench.Case("simulator", alt.GaussianPsf(1.0))],
                         ids=["alt", "simulator"])
def test_sigma_1_gaussian_at_5000_e_meets_the_goals_on_both_renderers(case):
    measure = bench.measure_alt if case.renderer == "alt" else bench.measure_simulator
    (row,) = measure(case, (5000.0,), 2, 11)
    assert row["stars"] >= 90 and row["stars_snr_ge_10"] == row["stars"] and 40 < row["median_snr"] < 90
    assert row["detected_snr_ge_10"] >= 0.99
    assert 0.7 < row["ratio"] <= 1.3  # at the bound (not below it: the bound is a bound)
    photon_limit = np.sqrt(2 * (1.0 + 1.0 / 12.0) / 5000.0)  # sky and read noise add to it
    assert photon_limit < row["crb_px"] < 1.6 * photon_limit


@pytest.mark.slow
def test_quick_run_writes_its_section_and_json(tmp_path):
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    results = bench.main(["--quick", "--output", str(out)])
    text = out.read_text()
    assert "## Other\n\nkept" in text and "## Centroiding across PSFs\n" in text and "issue" not in text
    assert "python -m bench.bench_psf_range --quick --output docs/BENCHMARKS.md" in text
    saved = json.loads((tmp_path / "bench_psf_range.json").read_text())
    assert saved["meta"]["quick"] and len(saved["rows"]) == len(results["rows"]) == 3 * 3 * 2
    assert {r["renderer"] for r in saved["rows"]} == {"simulator", "alt"}
    assert saved["false_detections"]["alt"]["frames"] == 2
    # At the sigma the centroider assumes, both renderers agree that the goals are met.
    for renderer in ("simulator", "alt"):
        row = next(r for r in saved["rows"] if r["renderer"] == renderer and r["psf"] == "Gaussian σ 1"
                   and r["flux_e"] == 5000.0)
        assert row["detection_met"] and row["ratio_met"]
