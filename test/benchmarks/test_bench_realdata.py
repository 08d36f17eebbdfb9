# SPDX-License-Identifier: Apache-2.0
"""
The real-image benchmark (bench/bench_realdata.py).

Its scoring against known rotations (no corpus needed) and its report. The corpus itself is
solved in test_realdata_corpus.py.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_realdata as bench  # noqa: E402
from star_tracker.models.attitude import radec_roll_to_matrix, rotation_vector_to_matrix  # noqa: E402

ARCSEC = math.radians(1.0 / 3600.0)
REFERENCE = radec_roll_to_matrix(math.radians(181.2), math.radians(16.8), math.radians(-4.4))  # sensor -> ICRS


def rotated(reference: np.ndarray, sensor_axis: tuple[float, float, float], angle_rad: float) -> np.ndarray:
    """Return `reference` (sensor -> ICRS) turned by angle_rad [rad] about a sensor-frame axis."""
    return reference @ rotation_vector_to_matrix(np.asarray(sensor_axis, float) * angle_rad)


def fake_image(reference: np.ndarray | None = REFERENCE) -> bench.CorpusImage:
    return bench.CorpusImage("fake", Path("/nowhere/fake.png"), "nobody/fake", 1024, 768, 10.0, reference, "high")


def test_reference_itself_has_no_error():
    boresight, roll = bench.attitude_errors(REFERENCE, REFERENCE)
    assert boresight == pytest.approx(0.0, abs=1e-9) and roll == pytest.approx(0.0, abs=1e-9)


def test_rotation_about_the_boresight_is_roll_only():
    angle = 30.0 * ARCSEC
    boresight, roll = bench.attitude_errors(rotated(REFERENCE, (0, 0, 1), angle), REFERENCE)
    assert boresight == pytest.approx(0.0, abs=1e-9)
    assert roll == pytest.approx(angle, rel=1e-6)
    _, roll_other_way = bench.attitude_errors(rotated(REFERENCE, (0, 0, 1), -angle), REFERENCE)
    assert roll_other_way == pytest.approx(angle, rel=1e-6)  # reported as a magnitude


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 1, 0), (math.sqrt(0.5), -math.sqrt(0.5), 0)])
def test_rotation_across_the_boresight_is_boresight_error(axis):
    angle = 45.0 * ARCSEC
    boresight, roll = bench.attitude_errors(rotated(REFERENCE, axis, angle), REFERENCE)
    assert boresight == pytest.approx(angle, rel=1e-6)
    assert roll < 1e-3 * ARCSEC  # second order in the tilt


def test_within_one_arcminute_is_judged_on_the_boresight():
    image = fake_image()
    assert bench.score(rotated(REFERENCE, (1, 0, 0), 59.0 * ARCSEC), image)["within_1arcmin"] is True
    assert bench.score(rotated(REFERENCE, (0, 1, 0), 61.0 * ARCSEC), image)["within_1arcmin"] is False
    large_roll = bench.score(rotated(REFERENCE, (0, 0, 1), math.radians(0.5)), image)
    assert large_roll["within_1arcmin"] is True and large_roll["roll_error_rad"] == pytest.approx(math.radians(0.5))
    unscored = bench.score(REFERENCE, fake_image(reference=None))
    assert unscored == {"boresight_error_rad": None, "roll_error_rad": None, "within_1arcmin": None}
    assert bench.score(None, image)["within_1arcmin"] is None


def test_field_groups_split_at_ten_percent():
    images = [bench.CorpusImage(str(f), Path("x"), "s", 100, 100, f, None, None)
              for f in (6.07, 6.1, 17.16, 25.39, 27.11, 36.8)]
    groups = bench.field_groups(images)
    assert groups == [(6.07, 6.1), (17.16, 17.16), (25.39, 27.11), (36.8, 36.8)]
    assert bench.group_of(images[4], groups) == (25.39, 27.11)


def test_missing_corpus_is_named(tmp_path):
    with pytest.raises(bench.CorpusMissing, match="real-image corpus not found.*--corpus"):
        bench.find_corpus(tmp_path / "absent")
    assert bench.main(["--corpus", str(tmp_path / "absent")]) == 2


def test_report_rows_and_summary(tmp_path):
    image = fake_image()
    good = {"solved": True, "status": "solved", "matched": 12, "time_s": 0.5,
            **bench.score(rotated(REFERENCE, (1, 0, 0), 20.0 * ARCSEC), image)}
    miss = {"solved": False, "status": "no_match", "matched": 0, "time_s": 5.0,
            **bench.score(None, image)}
    rows = [{"id": "fake", "source": "nobody/fake", "fov_h_deg": 10.0, "has_reference": True,
             "solvers": {"ours": good, "tetra3rs": miss}}]
    results = {"images": rows, "summary": bench.summarize(rows, ["ours", "tetra3rs"]), "peer_databases": {},
               "meta": {"elapsed_s": 1.0, "peers": ["tetra3rs"], "command": "test"}}
    assert results["summary"]["ours"]["within_1arcmin"] == 1 and results["summary"]["tetra3rs"]["solved"] == 0
    assert results["summary"]["ours"]["median_boresight_error_rad"] == pytest.approx(20.0 * ARCSEC)
    text = bench.render_markdown(results)
    assert text.startswith("## Real images") and "| fake | nobody/fake | 10.00 | yes / **yes** | 12 | 20.0 |" in text
    doc = tmp_path / "BENCHMARKS.md"
    doc.write_text("# Benchmarks\n\n## Soak\n\nkeep me\n")
    bench.write_section(doc, text)
    bench.write_section(doc, text)  # idempotent
    body = doc.read_text()
    assert "keep me" in body and body.count("## Real images") == 1


def test_time_goal_counted_both_ways():
    """Faster than a peer from decoded pixels (the peer's own timing) while slower as a whole command."""
    image = fake_image()
    solved = bench.score(rotated(REFERENCE, (1, 0, 0), 20.0 * ARCSEC), image)
    ours = {"solved": True, "status": "solved", "matched": 12, "time_s": 0.5, "pixels_time_s": 0.3, **solved}
    peer = {"solved": True, "status": "solved", "matched": 10, "time_s": 0.4, **solved}
    rows = [{"id": "fake", "source": "nobody/fake", "fov_h_deg": 10.0, "has_reference": True,
             "solvers": {"ours": ours, "cedar-solve": peer}}]
    results = {"images": rows, "summary": bench.summarize(rows, ["ours", "cedar-solve"]), "peer_databases": {},
               "meta": {"elapsed_s": 1.0, "peers": ["cedar-solve"], "command": "test"}}
    text = bench.render_markdown(results)
    assert "faster on 0 of the 1 images cedar-solve solves" in text and "from decoded pixels on 1 of 1" in text
    assert "| 0.50 (0.30) |" in text and results["summary"]["ours"]["median_pixels_time_s"] == pytest.approx(0.3)


def test_stage_table_names_where_our_time_goes():
    """The time-goal table: cedar-solve's time, the other peer's, ours from pixels split into its stages."""
    image = fake_image()
    solved = bench.score(rotated(REFERENCE, (1, 0, 0), 20.0 * ARCSEC), image)
    fast = {"solved": True, "status": "solved", "matched": 12, "time_s": 0.5, "pixels_time_s": 0.03,
            "stage_times_s": {"centroid": 0.02, "solve": 0.009}, **solved}
    slow = dict(fast, pixels_time_s=0.06, stage_times_s={"centroid": 0.045, "solve": 0.012})
    cedar = {"solved": True, "status": "solved", "matched": 10, "time_s": 0.04, **solved}
    failed = {"solved": False, "status": "no_match", "matched": 0, "time_s": 5.0, **bench.score(None, image)}
    rows = [{"id": name, "source": "nobody/fake", "fov_h_deg": 10.0, "has_reference": True,
             "solvers": {"ours": ours, "tetra3rs": failed, "cedar-solve": cedar}}
            for name, ours in (("quick", fast), ("slow", slow))]
    rows.append({"id": "unsolved-by-cedar", "source": "nobody/fake", "fov_h_deg": 10.0, "has_reference": True,
                 "solvers": {"ours": fast, "tetra3rs": failed, "cedar-solve": failed}})
    results = {"images": rows, "summary": bench.summarize(rows, ["ours", "tetra3rs", "cedar-solve"]),
               "peer_databases": {}, "meta": {"elapsed_s": 1.0, "peers": ["tetra3rs", "cedar-solve"],
                                              "command": "test"}}
    text = bench.render_markdown(results)
    assert "| quick | 40.0 | not solved | 30.0 | 20.0 | 9.0 | **0.75** |" in text
    assert "| slow | 40.0 | not solved | 60.0 | 45.0 | 12.0 | 1.50 |" in text
    assert "| unsolved-by-cedar | 40.0" not in text  # the goal counts the images cedar-solve solves


def test_quick_solves_are_timed_three_times_slow_ones_once(monkeypatch):
    """A solver's time is the median of TIMED_RUNS runs under REPEAT_BELOW_S, else one run's (a peer's 5 s failures)."""
    calls = []
    assert bench._timed(lambda: calls.append(1) or "result")[::2] == ("result", bench.TIMED_RUNS)
    assert len(calls) == bench.TIMED_RUNS
    monkeypatch.setattr(bench, "REPEAT_BELOW_S", 0.0)
    calls.clear()
    result, seconds, runs = bench._timed(lambda: calls.append(1) or "slow")
    assert (result, runs, len(calls)) == ("slow", 1, 1) and seconds >= 0.0
