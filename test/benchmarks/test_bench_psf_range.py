# SPDX-License-Identifier: Apache-2.0
"""
The PSF-range centroiding benchmark (bench/bench_psf_range.py).

Its scoring against known positions, a few of its cases at the centroider's defaults (today's
centroider meets the goals at the sigma it assumes, 1 px), its trials on the campaign engine
(a case's tallies survive the record's columns; the quick sizes on one and on two local
workers are the same records, the rows the benchmark's loop measured in this process, and
meet the goals against the truth), and the quick run's report.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import alt_renderer as alt  # noqa: E402
from bench import bench_psf_range as bench  # noqa: E402
from bench.campaign_trials import records, run_trials  # noqa: E402
from star_tracker.centroid.spots import Spots  # noqa: E402

TIMING = ("frame_ms", "median_ms")  # measured on the worker that ran the case


def untimed(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in TIMING}


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


def test_tasks_number_the_cases_then_each_renderers_star_free_frames():
    options = bench.PsfRangeOptions(quick=True, frames=1, false_frames=2)
    assert options.trials == 9 + 4 and options.fluxes == bench.QUICK_FLUXES
    assert [options.unit(t) for t in (0, 8, 9, 10, 11, 12)] == [
        ("case", None, 0), ("case", None, 8), ("false", "simulator", 0), ("false", "simulator", 1),
        ("false", "alt", 0), ("false", "alt", 1)]
    with pytest.raises(ValueError):
        options.unit(13)
    assert bench.PsfRangeOptions().trials == 22 + 20 and bench.PsfRangeOptions().fluxes == bench.FLUXES
    for bad in ({"frames": 0}, {"false_frames": 0}):
        with pytest.raises(ValueError):
            bench.PsfRangeOptions(**bad)


def test_a_cases_tallies_survive_the_records_columns():
    rng = np.random.default_rng(3)
    scores = {}
    for flux, stars, frames in ((1000.0, 7, 2), (5000.0, 0, 1), (30000.0, 5, 3)):  # one flux with no star scored
        scored = bench.Scored()
        scored.snr, scored.hit = list(rng.random(stars) * 40), list(rng.random(stars) > 0.3)
        scored.err2 = list(np.append(rng.random(stars - 1), np.nan) if stars else [])  # NaN: a star found by no spot
        scored.crb = list(rng.random(stars))
        scored.extra, scored.ms = list(rng.integers(0, 3, frames)), list(rng.random(frames) * 50)
        scores[flux] = scored
    row = {"task": 0, "seed": 1, "error": "", "part": "case", "renderer": "alt", "index": 0,
           **bench.scores_columns(scores)}
    (back,) = records(pa.Table.from_pylist([row], schema=bench.PsfRangeTrials.schema()))
    again = bench.record_scores(back, tuple(scores))
    assert list(again) == list(scores)
    for flux, scored in scores.items():
        np.testing.assert_equal(again[flux].arrays(), scored.arrays())
        np.testing.assert_equal(again[flux].row(), scored.row())


@pytest.mark.slow  # two local clusters and the quick run's eleven trials on each
def test_trials_on_one_and_two_workers_are_the_loops_rows_and_meet_the_goals():
    options = bench.PsfRangeOptions(quick=True, frames=1, false_frames=1)
    runs = []
    for workers in (1, 2):
        runs.append(run_trials(bench.PsfRangeTrials(), options.trials, dataclasses.asdict(options),
                               argparse.Namespace(workers=workers, scheduler=None, campaign_output=None)))
    (one, run_one), (two, run_two) = runs
    assert run_one["threads"] == 1 and run_two["threads"] == 2
    assert one.column("error").to_pylist() == [""] * options.trials
    np.testing.assert_equal(records(one.drop_columns(["frame_ms"])), records(two.drop_columns(["frame_ms"])))
    trials = records(one)
    todo = bench.cases(True)
    rows = {r["index"]: bench.case_rows(todo[r["index"]], bench.record_scores(r, options.fluxes))
            for r in trials if r["part"] == "case"}
    assert sorted(rows) == list(range(len(todo)))
    # A case's rows are what the benchmark's loop measured for it (seeded 1700 + its number).
    for index in (0, 3):  # the simulator's and the alt renderer's Gaussian sigma 0.6
        measure = bench.measure_simulator if todo[index].renderer == "simulator" else bench.measure_alt
        here = measure(todo[index], options.fluxes, 1, 1700 + index)
        np.testing.assert_equal([untimed(r) for r in rows[index]], [untimed(r) for r in here])
    # Against the truth: every quick row (sigma 0.6-2 px, Gaussian and Moffat, median SNR 12-66)
    # detects its SNR >= 10 stars and measures them at the Cramér-Rao bound (not below it).
    for row in (r for case in rows.values() for r in case):
        assert row["stars_snr_ge_10"] >= 40 and row["detected_snr_ge_10"] >= 0.99 and row["detection_met"], row
        assert 0.7 < row["ratio"] < 1.5, row
    spots = {r["renderer"]: r["spots"] for r in trials if r["part"] == "false"}
    assert sorted(spots) == ["alt", "simulator"] and max(spots.values()) <= bench.FALSE_GOAL


@pytest.mark.slow
def test_quick_run_writes_its_section_and_json(tmp_path):
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    results = bench.main(["--quick", "--workers", "2", "--output", str(out)])
    text = out.read_text()
    assert "## Other\n\nkept" in text and "## Centroiding across PSFs\n" in text and "issue" not in text
    assert "python -m bench.bench_psf_range --quick --workers 2 --output docs/BENCHMARKS.md" in text
    assert "Cases and star-free frames: trials on the campaign engine: 13 on 2 worker(s)" in text
    assert "none raised" in text and results["meta"]["trial_errors"] == []
    saved = json.loads((tmp_path / "bench_psf_range.json").read_text())
    assert saved["meta"]["quick"] and len(saved["rows"]) == len(results["rows"]) == 3 * 3 * 2
    assert {r["renderer"] for r in saved["rows"]} == {"simulator", "alt"}
    assert saved["false_detections"]["alt"]["frames"] == 2
    # At the sigma the centroider assumes, both renderers agree that the goals are met.
    for renderer in ("simulator", "alt"):
        row = next(r for r in saved["rows"] if r["renderer"] == renderer and r["psf"] == "Gaussian σ 1"
                   and r["flux_e"] == 5000.0)
        assert row["detection_met"] and row["ratio_met"]
