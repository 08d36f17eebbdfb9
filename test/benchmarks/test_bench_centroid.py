# SPDX-License-Identifier: Apache-2.0
"""
The centroiding benchmark's trials on the campaign engine (bench/bench_centroid.py).

Its tasks number the accuracy points, then the star-free frames, then the roll frames; a few
trials through the engine on one and on two local workers are the same records, an accuracy
point's record is what the benchmark's loop measured in this process, and the measured errors
stand against the truth (at the Cramér–Rao bound for the fitted variants, within a few times
it for the centres of gravity; no false detection on a star-free frame; the arc fit of curved
streaks well below the straight segment's error).
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_centroid as bench  # noqa: E402
from bench.campaign_trials import records, run_trials  # noqa: E402
from star_tracker.centroid import CentroidConfig  # noqa: E402

# SNR 100, no smear and 20 px, one frame each: 8 accuracy points, then one star-free and one roll frame.
SMALL = bench.CentroidTrialOptions(snrs="100", smears_px="0,20", frames=1, purity_frames=1, roll_frames=1)


def engine_run(kind, options, workers: int, trials: int):
    """Run `trials` trials of `kind` on `workers` local worker processes: (table, the engine's run)."""
    return run_trials(kind, trials, dataclasses.asdict(options),
                      argparse.Namespace(workers=workers, scheduler=None, campaign_output=None))


def test_tasks_number_the_accuracy_points_then_the_star_free_then_the_roll_frames():
    assert SMALL.trials == 10 and len(SMALL.points) == 8
    assert SMALL.points[0] == ("cog", "cog", False, 0, 100)
    assert SMALL.points[-1] == ("auto + rate", "auto", True, 20, 100)
    assert [SMALL.unit(t) for t in (0, 7, 8, 9)] == [("accuracy", 0), ("accuracy", 7), ("purity", 0), ("roll", 0)]
    with pytest.raises(ValueError):
        SMALL.unit(10)
    assert bench.QUICK.trials == 4 * 2 * 4 + 3 + 1 and bench.CentroidTrialOptions().trials == 4 * 4 * 7 + 10 + 3
    for bad in ({"snrs": "5,x"}, {"smears_px": ""}, {"frames": 0}, {"roll_electrons": -1.0}):
        with pytest.raises(ValueError):
            bench.CentroidTrialOptions(**bad)


@pytest.mark.slow  # two local clusters and ten 1024² trials
def test_trials_on_one_and_two_workers_are_the_loops_records_and_stand_against_the_truth():
    (one, run_one), (two, run_two) = (engine_run(bench.CentroidTrials(), SMALL, workers, SMALL.trials)
                                      for workers in (1, 2))
    assert run_one["threads"] == 1 and run_two["threads"] == 2
    assert one.column("error").to_pylist() == [""] * SMALL.trials
    np.testing.assert_equal(records(one), records(two))  # no timing column: every value, NaN equal to NaN
    trials = records(one)
    assert [r["task"] for r in trials] == list(range(SMALL.trials))

    # An accuracy point is what the benchmark's loop measured for it (its own generator, seeded by SNR and smear).
    auto_smeared = next(r for r in trials if r["part"] == "accuracy" and r["method"] == "auto" and r["smear_px"] == 20)
    here = bench.measure_accuracy(100, 20, 1, bench.ACCURACY_SENSOR, np.random.default_rng(100 * 100 + 20),
                                  CentroidConfig(method="auto", gain_e_per_adu=4.0))
    assert {name: auto_smeared[name] for name in here} == here

    accuracy = [r for r in trials if r["part"] == "accuracy"]
    # Every star of the 8x8 grid whose streak lies inside the image is found.
    assert len(accuracy) == 8 and all(r["stars"] >= 50 and r["detected"] == 1.0 for r in accuracy)
    # The bound: no smear, the pixel-integrated Gaussian's, a little above the photon limit sqrt(2 sigma^2 / F).
    still = next(r for r in accuracy if r["smear_px"] == 0)
    photon_limit = np.sqrt(2.0 / still["flux_e"])
    assert photon_limit < still["crb_px"] < 1.6 * photon_limit
    for r in accuracy:
        if r["method"].startswith("auto"):
            assert 0.7 < r["ratio"] < 1.5, r  # the fits at the bound (not below it: the bound is a bound)
        else:
            assert 0.7 < r["ratio"] < 4.0, r  # centres of gravity within a few times it
    (purity,) = [r for r in trials if r["part"] == "purity"]
    assert purity["detections"] <= 1
    (roll,) = [r for r in trials if r["part"] == "roll"]
    arc, segment = (np.sqrt(np.mean(roll[c])) for c in ("roll_arc_err2_px2", "roll_segment_err2_px2"))
    assert roll["roll_arc_err2_px2"].size >= 35 and arc < 0.03 and arc < segment / 3
