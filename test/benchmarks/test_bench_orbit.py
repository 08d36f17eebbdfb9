# SPDX-License-Identifier: Apache-2.0
"""
The in-orbit benchmark (bench/bench_orbit.py).

Its interval comparison, its independent geometry (astropy) on constructed cases, and the quick
run judged on counted outcomes and truth: no wrong attitude, the fused attitude always
available, the blinded intervals where astropy puts them, the Moon and a planet in the field,
the aberration's bias and its correction.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_orbit as bench  # noqa: E402
from star_tracker.models.ephemeris import load_ephemeris  # noqa: E402


def test_intervals_pair_and_measure_their_boundaries():
    simulated = np.array(["tracking_possible"] * 3 + ["blinded_sun"] * 4 + ["tracking_possible"] * 3
                         + ["blinded_moon"] * 2)
    predicted = np.array(["tracking_possible"] * 2 + ["blinded_sun"] * 5 + ["tracking_possible"] * 5)
    assert bench.intervals(simulated == "blinded_sun") == [(3, 6)]
    comparison = bench.compare_intervals(simulated, predicted)
    sun, moon = comparison["blinded_sun"], comparison["blinded_moon"]
    assert (sun["simulated"], sun["predicted"], sun["max_offset_frames"], sun["unmatched"],
            sun["frames_differing"]) == (1, 1, 1, 0, 1)
    assert (moon["simulated"], moon["predicted"], moon["unmatched"]) == (1, 0, 1)
    assert comparison["occulted"] == {"simulated": 0, "predicted": 0, "max_offset_frames": 0, "unmatched": 0,
                                      "frames_differing": 0}


def test_astropy_statuses_on_constructed_geometry():
    """Over the subsolar point: the Earth's centre occults, the Sun blinds, and so does the lit limb 5 deg away."""
    t = bench.EPOCH_UNIX_S
    sun = load_ephemeris().sun_position(t)
    up = sun / np.linalg.norm(sun)
    r = up * (6_378_137.0 + 550e3)
    v = np.cross(up, [0.0, 0.0, 1.0])
    v *= 7600.0 / np.linalg.norm(v)
    limb = math.asin((bench.EXCLUSION.earth_radius_m + bench.EXCLUSION.atmosphere_height_m) / np.linalg.norm(r))
    side = np.cross(up, v) / np.linalg.norm(np.cross(up, v))
    above_limb = math.pi - limb - math.radians(5.0)  # from the zenith
    boresights = np.array([-up, up, math.cos(above_limb) * up + math.sin(above_limb) * side])
    out = bench.astropy_statuses(np.full(3, t), np.tile(r, (3, 1)), np.tile(v, (3, 1)), boresights)
    assert list(out["status"]) == ["occulted", "blinded_sun", "blinded_earth"]
    assert math.degrees(out["sun_angle_rad"][1]) < 0.1
    assert math.degrees(out["lit_earth_angle_rad"][2]) == pytest.approx(5.0, abs=0.05)


@pytest.mark.slow  # renders and solves ~200 frames: ~25 s
def test_quick_run_counts_and_truth(tmp_path):
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    results = bench.main(["--quick", "--jobs", "1", "--output", str(out)])
    text = out.read_text()
    assert "## Other\n\nkept" in text and bench.SECTION + "\n" in text
    assert "Command: `python -m bench.bench_orbit --quick --jobs 1 --output" in text
    saved = json.loads((tmp_path / "bench_orbit.json").read_text())
    assert saved["meta"]["quick"] and saved["meta"]["frames_per_head"] == results["meta"]["frames_per_head"] > 50
    assert {Path(f).name for f in saved["figures"]} == {"orbit_availability.png", "orbit_fused_error.png",
                                                        "orbit_sky.png"}
    heads, fusion = saved["heads"], saved["fusion"]
    # Availability: no wrong attitude anywhere; the fused attitude in every frame (head a stays clear).
    assert heads["a"]["wrong"] == heads["b"]["wrong"] == fusion["wrong"] == 0
    assert fusion["available_pct"] >= 99.5 and fusion["one_head"] > 0  # head b blinded by the Sun
    # The windows cross the Moon's and the Sun's exclusion for head b: the renderer's intervals are astropy's.
    b = heads["b"]["truth_vs_astropy"]
    assert b["blinded_sun"]["simulated"] >= 1 and b["blinded_moon"]["simulated"] >= 1
    assert heads["b"]["flooded"] > 0 and heads["b"]["solved_by_truth_status"]["blinded_sun"] == 0
    assert saved["goals"]["intervals"]
    # The Moon and a planet in the field: seen, never a wrong attitude.
    arcs = saved["arcs"]
    assert {row["target"] for row in arcs["arcs"]} == {"moon", "jupiter"}
    assert all(row["in_field"] > 0 for row in arcs["arcs"]) and arcs["wrong"] == 0
    assert any(saved["timeline"]["b"]["moon_in_field"])
    # Aberration: uncorrected, the attitude is off by the predicted ~15"; corrected, within arcseconds of the truth.
    aberration = saved["aberration"]
    assert aberration["solved_all"] >= 6
    uncorrected = aberration["moving_raw"]["cross_mean_arcsec"]
    assert uncorrected == pytest.approx(aberration["predicted_mean_arcsec"], rel=0.15) and uncorrected > 10.0
    assert aberration["moving_corrected"]["cross_mean_arcsec"] < 2.0
