# SPDX-License-Identifier: Apache-2.0
"""
The real-image benchmark (bench/bench_realdata.py) and the corpus it reads (bench/corpus.py).

Its scoring against known rotations, the dense references, the re-judging of stored solutions
and its report (no corpus needed). The corpus itself is solved in test_realdata_corpus.py.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_realdata as bench  # noqa: E402
from bench import corpus  # noqa: E402
from star_tracker.models.attitude import (matrix_to_quaternion, radec_roll_to_matrix,  # noqa: E402
                                          rotation_vector_to_matrix)

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
             "reference_confidence": "high",
             "solvers": {"ours": good, "tetra3rs": miss}}]
    results = {"images": rows, "summary": bench.summarize(rows, ["ours", "tetra3rs"]), "peer_databases": {},
               "meta": {"elapsed_s": 1.0, "peers": ["tetra3rs"], "command": "test"}}
    assert results["summary"]["ours"]["within_1arcmin"] == 1 and results["summary"]["tetra3rs"]["solved"] == 0
    assert results["summary"]["ours"]["median_boresight_error_rad"] == pytest.approx(20.0 * ARCSEC)
    text = bench.render_markdown(results)
    assert text.startswith("## Real images")
    assert "| fake | nobody/fake | 10.00 | astrometry.net (high) | yes / **yes** | 12 | 20.0 |" in text
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
             "reference_confidence": "high",
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
             "reference_confidence": "high",
             "solvers": {"ours": ours, "tetra3rs": failed, "cedar-solve": cedar}}
            for name, ours in (("quick", fast), ("slow", slow))]
    rows.append({"id": "unsolved-by-cedar", "source": "nobody/fake", "fov_h_deg": 10.0, "has_reference": True,
                 "reference_confidence": "high", "solvers": {"ours": fast, "tetra3rs": failed, "cedar-solve": failed}})
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


def _manifest(tmp_path: Path, entry: dict) -> Path:
    folder = tmp_path / "realdata"
    folder.mkdir(parents=True)
    base = {"id": "fake", "file": "fake.png", "source_repo": "nobody/fake", "width": 1024, "height": 768,
            "fov_h_deg": 10.0}
    (folder / "MANIFEST.json").write_text(json.dumps({"images": [dict(base, **entry)]}))
    return folder


def _sky(rotation: np.ndarray) -> tuple[float, float]:
    """RA, Dec [deg] of a rotation's boresight."""
    z = rotation[:, 2]
    return math.degrees(math.atan2(z[1], z[0])) % 360.0, math.degrees(math.asin(z[2]))


def test_dense_reference_moves_the_boresight_and_keeps_the_roll(tmp_path):
    """Where the manifest has a dense re-fit, the boresight is judged against its centre, the roll as before."""
    dense_truth = rotated(REFERENCE, (0.6, 0.8, 0.0), 90.0 * ARCSEC)  # the dense centre, 1.5' from the old one
    ra, dec = _sky(dense_truth)
    reference = {"quat_xyzw_sensor_to_icrs": matrix_to_quaternion(REFERENCE).tolist(), "confidence": "high"}
    folder = _manifest(tmp_path, {"reference": reference,
                                  "reference_dense": {"ra_deg": ra, "dec_deg": dec, "matched_stars": 2023}})
    image = corpus.load_corpus(folder)[0]
    assert image.dense_stars == 2023 and image.reference_kind == "dense re-fit"
    boresight, roll = corpus.attitude_errors(dense_truth, image.reference)
    assert boresight < 0.01 * ARCSEC and roll < 0.01 * ARCSEC  # the dense centre itself: no error
    old_boresight, _ = corpus.attitude_errors(dense_truth, REFERENCE)
    assert old_boresight == pytest.approx(90.0 * ARCSEC, rel=1e-6)  # against the few-star reference: 1.5' off
    # A solve rolled about its boresight keeps that roll against the moved reference.
    _, rolled = corpus.attitude_errors(rotated(dense_truth, (0, 0, 1), 40.0 * ARCSEC), image.reference)
    assert rolled == pytest.approx(40.0 * ARCSEC, rel=1e-3)
    # Inside `reference`, as the manifest's conventions also allow, it counts the same.
    inside = dict(reference, reference_dense={"ra_deg": ra, "dec_deg": dec, "matched_stars": 485})
    assert corpus.load_corpus(_manifest(tmp_path / "inside", {"reference": inside}))[0].dense_stars == 485


def test_without_a_dense_block_the_astrometry_net_reference_is_kept(tmp_path):
    reference = {"quat_xyzw_sensor_to_icrs": matrix_to_quaternion(REFERENCE).tolist(), "confidence": "low"}
    image = corpus.load_corpus(_manifest(tmp_path, {"reference": reference}))[0]
    assert image.dense_stars is None and image.reference_kind == "astrometry.net"
    assert np.allclose(image.reference, REFERENCE)
    assert corpus.load_corpus(_manifest(tmp_path / "none", {"reference": None}))[0].reference_kind is None


def test_stored_solutions_are_judged_again(tmp_path):
    """--from-json: a solution 1.5' from the old reference, at the dense centre, becomes within 1'."""
    dense_truth = rotated(REFERENCE, (1.0, 0.0, 0.0), 90.0 * ARCSEC)
    ra, dec = _sky(dense_truth)
    reference = {"quat_xyzw_sensor_to_icrs": matrix_to_quaternion(REFERENCE).tolist(), "confidence": "high"}
    old = bench.CorpusImage("fake", Path("/nowhere/fake.png"), "nobody/fake", 1024, 768, 10.0, REFERENCE, "high")
    stored = {"solved": True, "status": "solved", "matched": 40, "time_s": 0.1,
              "quat_xyzw_sensor_to_icrs": matrix_to_quaternion(dense_truth).tolist(), **bench.score(dense_truth, old)}
    unsolved = {"solved": False, "status": "no_match", "matched": 0, "time_s": 5.0,
                "quat_xyzw_sensor_to_icrs": None, **bench.score(None, old)}
    assert stored["within_1arcmin"] is False
    rows = [{"id": "fake", "source": "nobody/fake", "fov_h_deg": 10.0, "has_reference": True,
             "reference_confidence": "high",
             "solvers": {"ours": stored, "tetra3rs": unsolved}}]
    results = {"images": rows, "summary": bench.summarize(rows, ["ours", "tetra3rs"]), "peer_databases": {},
               "meta": {"elapsed_s": 1.0, "peers": ["tetra3rs"], "command": "test"}}
    path = tmp_path / "bench_realdata.json"
    path.write_text(json.dumps(results))
    folder = _manifest(tmp_path, {"reference": reference,
                                  "reference_dense": {"ra_deg": ra, "dec_deg": dec, "matched_stars": 600}})
    doc = tmp_path / "BENCHMARKS.md"
    assert bench.main(["--corpus", str(folder), "--from-json", str(path), "--output", str(doc)]) == 0
    judged = json.loads(path.read_text())
    ours = judged["images"][0]["solvers"]["ours"]
    assert ours["within_1arcmin"] is True and ours["boresight_error_rad"] < 0.01 * ARCSEC
    assert judged["summary"]["ours"]["within_1arcmin"] == 1 and judged["images"][0]["dense_stars"] == 600
    text = doc.read_text()
    assert "| fake | nobody/fake | 10.00 | dense re-fit, 600 stars | yes / **yes** |" in text
    assert "judged again" in text


def test_a_solution_not_stored_cannot_be_judged_again(tmp_path):
    reference = {"quat_xyzw_sensor_to_icrs": matrix_to_quaternion(REFERENCE).tolist(), "confidence": "high"}
    solved = {"solved": True, "status": "solved", "matched": 40, "time_s": 0.1,
              **bench.score(REFERENCE, fake_image())}  # an older results file: no quaternion
    rows = [{"id": "fake", "source": "nobody/fake", "fov_h_deg": 10.0, "has_reference": True,
             "reference_confidence": "high",
             "solvers": {"ours": solved}}]
    path = tmp_path / "old.json"
    path.write_text(json.dumps({"images": rows, "summary": {}, "peer_databases": {},
                                "meta": {"elapsed_s": 1.0, "peers": [], "command": "test"}}))
    folder = _manifest(tmp_path, {"reference": reference})
    assert bench.main(["--corpus", str(folder), "--from-json", str(path)]) == 1


def test_misses_are_listed_with_every_solver_and_the_known_cause():
    image = fake_image()
    off = {"solved": True, "status": "solved", "matched": 24, "time_s": 0.1,
           **bench.score(rotated(REFERENCE, (1, 0, 0), 138.0 * ARCSEC), image)}
    peer = {"solved": False, "status": "no_match", "matched": 0, "time_s": 0.1, **bench.score(None, image)}
    rows = [{"id": "ubst_webcam_w1", "source": "s", "fov_h_deg": 36.8, "has_reference": True,
             "reference_confidence": "high",
             "solvers": {"ours": off, "tetra3rs": peer}}]
    lines = bench.misses({"images": rows})
    assert "- ubst_webcam_w1: ours 2.3′ off with 24 stars, tetra3rs not solved. A 37° webcam field" in "\n".join(lines)
