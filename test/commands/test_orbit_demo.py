# SPDX-License-Identifier: Apache-2.0
"""
The LEO demo's report (commands/orbit_demo.py), on frames whose errors and statuses are known.

Head frames carry a truth and an estimate turned from it by a chosen rotation; the summary's
counts, RMS, bias and intervals, frames.csv and the pictures are checked against those choices.
"""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from star_tracker.commands.orbit_demo import intervals, summarize, write_frames_csv
from star_tracker.models.attitude import radec_roll_to_matrix, rotation_vector_to_matrix

ARCSEC = math.radians(1.0 / 3600.0)
INTERVAL_S = 3.0
T0_NS = 1_796_000_000_000_000_000


def stamp(i: int) -> int:
    return T0_NS + int(i * INTERVAL_S * 1e9)


def head_frames(statuses: list[str], error_rad: np.ndarray, wrong_at: int | None = None) -> dict:
    """Frames by stamp: truth, status, and an attitude off by error_rad (head axes) unless blinded/occulted."""
    frames = {}
    for i, status in enumerate(statuses):
        truth = radec_roll_to_matrix(0.01 * i, 0.3, 0.2)
        row = {"stamp_ns": stamp(i), "truth": truth, "status": status}
        if status in ("tracking", "lost_in_space"):
            error = error_rad if i != wrong_at else np.array([0.0, 90.0 * ARCSEC, 0.0])
            row["attitude"] = truth @ rotation_vector_to_matrix(error)
        frames[stamp(i)] = row
    return frames


def test_intervals_are_runs_of_one_blocked_status():
    statuses = ["tracking", "blinded_sun", "blinded_sun", "blinded_earth", "tracking", "blinded_sun", "occulted"]
    runs = intervals([stamp(i) for i in range(len(statuses))], statuses, INTERVAL_S)
    assert [(r["status"], r["frames"]) for r in runs] == [("blinded_sun", 2), ("blinded_earth", 1),
                                                          ("blinded_sun", 1), ("occulted", 1)]
    assert runs[0]["start_s"] == pytest.approx(stamp(1) * 1e-9) and runs[0]["end_s"] == pytest.approx(stamp(2) * 1e-9)
    # A missing frame (a gap longer than 1.5 intervals) ends a run.
    runs = intervals([stamp(0), stamp(1), stamp(3)], ["occulted"] * 3, INTERVAL_S)
    assert [r["frames"] for r in runs] == [2, 1]


def test_summary_counts_errors_bias_and_the_fused_gaps(tmp_path):
    statuses = ["lost_in_space", "tracking", "tracking", "blinded_moon", "blinded_moon", "tracking", "tracking"]
    error = np.array([1.0, -2.0, 5.0]) * ARCSEC
    frames = {"head1": head_frames(statuses, error, wrong_at=6), "head2": head_frames(["tracking"] * 7, -error)}
    fused = {}
    for i in (0, 1, 2, 5, 6):  # none at slots 3 and 4
        truth = frames["head2"][stamp(i)]["truth"]
        fused[stamp(i)] = {"stamp_ns": stamp(i), "truth": truth, "rotation": truth @ rotation_vector_to_matrix(error),
                           "axis_error": error}
    summary = summarize(frames, fused, ["head1", "head2"], INTERVAL_S)
    head1 = summary["head1"]
    assert (head1["frames"], head1["available"], head1["wrong"]) == (7, 5, 1)
    assert head1["status_counts"] == {"lost_in_space": 1, "tracking": 4, "blinded_moon": 2}
    assert [(r["status"], r["frames"]) for r in head1["blinded_intervals"]] == [("blinded_moon", 2)]
    four_good = np.array([np.hypot(1.0, 2.0)] * 4 + [90.0])
    assert head1["cross_boresight_arcsec_rms"] == pytest.approx(np.sqrt(np.mean(four_good ** 2)), rel=1e-6)
    assert summary["head2"]["error_arcsec_mean_xyz"] == pytest.approx([-1.0, 2.0, -5.0], abs=1e-6)
    assert summary["head2"]["roll_arcsec_rms"] == pytest.approx(5.0, rel=1e-6)
    fused_summary = summary["fused"]
    assert (fused_summary["frames"], fused_summary["available"], fused_summary["wrong"]) == (7, 5, 0)
    assert fused_summary["error_arcsec_rms_xyz"] == pytest.approx([1.0, 2.0, 5.0], rel=1e-6)
    assert list(fused_summary["by_heads_with_attitude"]) == ["2"]  # both heads solved every fused stamp
    assert fused_summary["by_heads_with_attitude"]["2"]["fusions"] == 5
    assert fused_summary["by_heads_with_attitude"]["2"]["error_arcsec_rms_xyz"] == pytest.approx([1, 2, 5], rel=1e-6)
    gaps = fused_summary["unavailable_intervals"]
    assert [g["frames"] for g in gaps] == [2]
    assert gaps[0]["start_s"] == pytest.approx(stamp(3) * 1e-9, abs=INTERVAL_S)

    write_frames_csv(frames, fused, ["head1", "head2"], tmp_path / "frames.csv")
    rows = list(csv.DictReader(open(tmp_path / "frames.csv")))
    assert [r["source"] for r in rows].count("head1") == 7 and [r["source"] for r in rows].count("fused") == 5
    blinded = [r for r in rows if r["source"] == "head1" and r["status"] == "blinded_moon"]
    assert len(blinded) == 2 and all(r["error_x_arcsec"] == "" for r in blinded)
    second = next(r for r in rows if r["source"] == "head2" and r["stamp_ns"] == str(stamp(1)))
    assert [float(second[f"error_{a}_arcsec"]) for a in "xyz"] == pytest.approx([-1.0, 2.0, -5.0], abs=1e-3)


def test_the_pictures_are_written(tmp_path):
    pytest.importorskip("matplotlib")
    from star_tracker.visualize_orbit import availability_figure, fused_error_figure, sky_figure

    statuses = ["tracking", "blinded_sun", "tracking"]
    error = np.array([1.0, 1.0, 3.0]) * ARCSEC
    frames = {"head1": head_frames(statuses, error)}
    fused = {stamp(i): {"stamp_ns": stamp(i), "truth": np.eye(3), "rotation": np.eye(3), "axis_error": error}
             for i in (0, 2)}
    start_s = T0_NS * 1e-9
    for path in (availability_figure(frames, fused, ["head1"], start_s, tmp_path / "availability.png"),
                 fused_error_figure(fused, start_s, tmp_path / "fused_error.png"),
                 sky_figure(frames, ["head1"], start_s, start_s + 9.0, tmp_path / "sky.png")):
        assert path is not None and path.stat().st_size > 5000
