# SPDX-License-Identifier: Apache-2.0
"""
The tracking benchmark's trials on the campaign engine (bench/bench_tracking.py).

The units (one sequence or delay trial per task) come in the order and number the benchmark's
loops always ran them; a sequence's per-frame records survive their trip through the record's
list columns (gap frames, failed tracking attempts, streak fits, tetra3rs's records when it is
installed); the first quick sequences run through the engine on 1 and on 2 local workers give
the same records (times aside), and their frames are identified against the truth: every id
the truth star's, the attitude within a few stated sigmas of the true one.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_tracking as bench  # noqa: E402
from bench.campaign_trials import errors, run_trials  # noqa: E402


def test_units_follow_the_plan():
    units = bench.plan_units(bench.QUICK)
    parts = [u.part for u in units]
    # Quick: 4 constant rates x 1 run, 2 slews, 2 rates x 4 gap kinds, 2 rates x 3 solve times.
    assert parts == ["constant"] * 4 + ["slew"] * 2 + ["reacquisition"] * 8 + ["delay"] * 6
    assert [u.case for u in units[:6]] == ["0 deg/s", "1 deg/s", "2 deg/s", "5 deg/s", "slew 0.5 deg/s^2",
                                           "slew 2 deg/s^2"]
    assert len({(u.part, u.case, u.run) for u in units}) == len(units)
    full = bench.plan_units(bench.Plan())
    assert len(full) == bench.TrackingTrials.default_trials == 4 * 8 + 2 * 2 + 4 + 3 + 2 * 4 * 4 + 2 * 3 * 6


@pytest.mark.slow  # builds the bench (database, renderer, tetra3rs) and tracks 10 frames: ~15 s
def test_sequence_records_survive_the_columns():
    kind = bench.TrackingTrials()
    shared = kind.prepare(bench.TrackingOptions(quick=True, peers=True))
    rng = np.random.default_rng(7)
    motion = bench.ConstantRateMotion(bench.random_pointing(rng), 2.0 * bench.DEG * bench.random_direction(rng))
    seq = shared.bench.run("test", 3, motion, 10, seed=11, gaps={4: "blank", 5: "two_spots"}, streaks=True)
    seq.accel_steps, seq.slew_axis, seq.accel_rad_s2 = [0.5, 1.0, 2.0, 2.5], np.array([0.6, -0.8, 0.0]), 0.01
    frames = seq.records
    assert frames[4]["gap"] == "blank" and "track_failure" in frames[4] and "gate_px" in frames[4]
    assert all("streak" in r for r in frames) and any(r["streak"] is not None for r in frames)
    if shared.bench.peer is not None:
        assert any("propagated" in r["peer"] for r in frames) and any("track_ms" in r["peer"] for r in frames)
    record = {"part": "constant", "case": seq.case, "run": seq.run, "peer_version": None, "peer_patterns": None,
              **bench.sequence_columns(seq)}
    table = pa.Table.from_pylist([record], schema=pa.schema(kind.columns))
    back = bench.sequence_from_record(table.to_pylist()[0])
    assert (back.case, back.run, back.accel_steps, back.accel_rad_s2) == ("test", 3, seq.accel_steps, 0.01)
    np.testing.assert_array_equal(back.slew_axis, seq.slew_axis)
    assert back.records == frames  # every key present or absent as it was, every value equal

    delay = bench.run_unit(shared.bench, shared.plan, bench.plan_units(shared.plan)[-1])
    row = {f"delay_{key}": delay.get(key) for key, _ in bench.DELAY_KEYS}
    again = bench.delay_from_record(pa.Table.from_pylist([row], schema=pa.schema(bench.DELAY_COLUMNS)).to_pylist()[0])
    assert again == delay and list(again) == list(delay)  # the keys in the trial's order (the JSON's)


@pytest.mark.slow  # two local clusters, three 20-frame sequences each: ~1-2 min on a busy 2-core machine
def test_engine_records_equal_on_one_and_two_workers_and_frames_identified():
    kind = bench.tracking_kind()
    options = {"quick": True, "peers": False}
    tables = [run_trials(kind, 3, options, argparse.Namespace(workers=workers), seed=bench.SEED)[0]
              for workers in (1, 2)]
    for table in tables:
        assert errors(table) == []
    one, two = (t.drop_columns(list(bench.TIMING_COLUMNS)) for t in tables)
    assert one.equals(two)

    units = bench.plan_units(bench.QUICK)
    for unit, row in zip(units, tables[1].to_pylist()):
        seq = bench.sequence_from_record(row)
        assert (seq.case, seq.run, len(seq.records)) == (unit.case, unit.run, bench.QUICK.frames_per_run)
        # Every frame solved, every id the truth star nearest its spot; tracked after the first.
        assert all(r["solved"] and r["correct"] and not r["incorrect"] for r in seq.records)
        assert [r["mode"] for r in seq.records] == ["lost_in_space"] + ["tracking"] * (len(seq.records) - 1)
        # The attitude against the truth: within 5 stated sigmas on every axis.
        error = np.abs(np.array([r["error_vector"] for r in seq.records]))
        sigma = np.array([r["stated_sigma"] for r in seq.records])
        assert np.all(error < 5.0 * sigma), (unit.case, float(np.max(error / sigma)))
        assert ("streak" in seq.records[0]) == (unit.rate_deg_s in (1.0, 2.0))  # first runs at 1 and 2 deg/s: streaks
