# SPDX-License-Identifier: Apache-2.0
"""
The attitude benchmark (bench/bench_attitude.py) on the campaign engine.

Its tasks number the cases' frames in order; a frame's record survives the trip through the
kind's typed columns unchanged (a frame that raised is counted, not dropped); the benchmark's
command on one and on two local workers stores the same records and the same figures, the same
as the benchmark's chain in this process (the frames it ran before the engine), judged against
the truth (every frame identified with its own stars, at rest within a few arcseconds), and
writes its section beside the others.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_attitude as bench  # noqa: E402
from star_tracker.campaign import CampaignSpec  # noqa: E402
from star_tracker.campaign.results import ResultStore  # noqa: E402
from star_tracker.models.attitude import ARCSEC  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
TIMING = ("render_ms", "centroid_ms", "identify_ms")
FRAMES = 4  # at rest; 2 under each of the 5 rates


def test_tasks_number_the_cases_frames_in_order():
    options = bench.AttitudeOptions(6)
    assert bench.case_frame_counts(6) == [6, 3, 3, 3, 3, 3] and options.trials == 21
    assert [options.locate(t) for t in (0, 5, 6, 8, 9, 20)] == [(0, 0), (0, 5), (1, 0), (1, 2), (2, 0), (5, 2)]
    assert bench.AttitudeOptions(1).trials == 6  # each rate case at least one frame
    with pytest.raises(IndexError):
        options.locate(21)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError):
            bench.AttitudeOptions(bad)


def test_a_frame_record_survives_the_columns():
    rng = np.random.default_rng(1)
    stars = 7
    record = {"render_ms": 5.0, "centroid_ms": 9.5, "identify_ms": 2.25, "spots": 31, "solved": True,
              "error": rng.normal(size=3) * 1e-6, "nees": (2.5, 1.5, 0.25), "stars": stars,
              "predicted_var": (3e-12, 4e-11), "wrong_ids": 1, "star_chi2": np.append(rng.random(stars - 1), np.nan),
              "star_snr": rng.random(stars) * 100, "star_flags": np.array([0, 1, 4, 0, 2, 0, 0], np.uint32),
              "star_clipped": np.array([False, True, False, False, False, False, True]),
              "star_hp": np.append(rng.random(stars - 1) * 7, np.nan), "star_neighbour_px": rng.random(stars) * 50,
              "star_sigma_px": rng.random(stars) * 0.1, "clipped_frame": True,
              "category": {"saturated": True, "blended": False, "crowded": True, "clean": False},
              "nees_floored": (1.0, 2.0, 3.0), "nees_isolated": (4.0, 5.0, 6.0), "nees_all_kept": (7.0, 8.0, 9.0),
              "nees_isotropic": (1.5, 2.5, 3.5)}  # nees_unclipped left out (fewer than 4 unclipped stars)
    unsolved = {**{k: record[k] for k in (*TIMING, "spots")}, "solved": False}
    rows = [{"task": task, "seed": 1, "error": "", "case": 0, "frame": task, **bench.frame_columns(r)}
            for task, r in enumerate((record, unsolved))]
    rows.append({"task": 2, "seed": 1, "error": "ValueError: boom"})  # a frame that raised: its columns null
    table = pa.Table.from_pylist(rows, schema=bench.AttitudeFrames.schema())
    per_case, failed = bench.case_records(table, frames=6)
    assert [len(case) for case in per_case] == [2, 0, 0, 0, 0, 0]
    assert _same(per_case[0][0], record) and per_case[0][1] == unsolved
    assert failed == ["case 0 frame 2, task 2: ValueError: boom"]


def _same(a: dict, b: dict) -> bool:
    """Whether two frame records are equal: same keys, arrays equal with their dtype (NaN equal to NaN)."""
    if a.keys() != b.keys():
        return False
    for key in a:
        x, y = a[key], b[key]
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not (isinstance(x, np.ndarray) and isinstance(y, np.ndarray) and x.dtype == y.dtype
                    and np.array_equal(x, y, equal_nan=x.dtype.kind == "f")):
                return False
        elif x != y:
            return False
    return True


def _untimed(per_case: list[list[dict]]) -> list[list[dict]]:
    return [[{k: v for k, v in r.items() if k not in TIMING} for r in case] for case in per_case]


def _run(directory: Path, *options: str) -> tuple[dict, list[list[dict]]]:
    """
    Run the benchmark (--frames FRAMES) as its command does, keeping the records in `directory`.

    Return its results JSON and its frames' records (case_records of the stored table). A
    subprocess: a local cluster's scheduler runs in the process that starts it.
    """
    done = subprocess.run([sys.executable, "-m", "bench.bench_attitude", "--frames", str(FRAMES), *options,
                           "--campaign-output", str(directory), "--json", str(directory / "results.json")],
                          cwd=REPO, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    options = bench.AttitudeOptions(FRAMES)
    spec = CampaignSpec(bench.AttitudeFrames.name, options.trials, bench.SEED, bench.AttitudeFrames.default_batch,
                        {"frames": FRAMES})
    table = ResultStore(directory / bench.AttitudeFrames.name, spec, bench.AttitudeFrames.schema()).read()
    per_case, failed = bench.case_records(table.sort_by("task"), FRAMES)
    assert failed == []
    return json.loads((directory / "results.json").read_text()), per_case


def _figures(results: dict) -> dict:
    """Return the results without what timing, the date, the command and the engine change."""
    meta = {k: v for k, v in results["meta"].items()
            if k not in ("command", "date", "elapsed_s", "machine", "engine", "engine_run")}
    cases = [{k: v for k, v in c.items() if k not in ("timing_ms", "frames_s")} for c in results["cases"]]
    return {**results, "meta": meta, "cases": cases}


@pytest.mark.slow  # two runs of 14 frames (local clusters of 1 and 2 workers) and the chain here: ~1 min, busy 2 cores
def test_one_and_two_workers_run_the_same_frames_as_the_chain_and_match_the_truth(tmp_path):
    out = tmp_path / "two" / "BENCHMARKS.md"
    out.parent.mkdir()
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    results_one, one = _run(tmp_path / "one", "--workers", "1")
    results_two, two = _run(tmp_path / "two", "--jobs", "2", "--output", str(out))  # --jobs: alias of --workers
    assert [len(case) for case in one] == [len(case) for case in two] == bench.case_frame_counts(FRAMES)
    assert all(_same(a, b) for x, y in zip(_untimed(one), _untimed(two)) for a, b in zip(x, y))
    assert _figures(results_one) == _figures(results_two)
    for results, workers in ((results_one, 1), (results_two, 2)):
        meta = results["meta"]
        assert meta["failed_trials"] == [] and meta["engine_run"]["threads"] == workers
        assert f"--workers {workers} --campaign-output" in meta["command"] and f"{workers} worker(s)" in meta["engine"]

    # The benchmark's chain in this process on the frames case_frames draws (its loop before the engine).
    chain = bench.Chain()
    for index, ((_, kind, rate), case) in enumerate(zip(bench.CASES, _untimed(one))):
        here = [chain.run_frame(*frame) for frame in bench.case_frames(index, kind, rate, len(case))]
        assert all(_same(a, b) for a, b in zip(case, _untimed([here])[0])), bench.CASES[index]

    # Truth: every frame identified with its own stars; at rest within a few arcseconds.
    every = [r for case in one for r in case]
    assert all(r["solved"] and r["wrong_ids"] == 0 and r["stars"] >= 10 for r in every)
    rest = np.array([r["error"] for r in one[0]]) / ARCSEC
    assert np.all(np.hypot(rest[:, 0], rest[:, 1]) < 3.0) and np.all(np.abs(rest[:, 2]) < 20.0)
    cases = results_one["cases"]
    assert [c["frames"] for c in cases] == bench.case_frame_counts(FRAMES)
    assert all(c["identified_pct"] == 100.0 and c["wrong_id_frames"] == 0 and c["failed_frames"] == 0 for c in cases)
    assert cases[0]["cross_rms_arcsec"] < 3.0 and results_one["pooled_moving"]["frames"] == 5 * FRAMES // 2

    # The section, beside the one it keeps, with where the trials ran.
    text = out.read_text()
    assert "kept" in text and bench.SECTION in text and results_two["meta"]["engine"] in text
    assert (out.parent / "images" / "attitude_error_vs_rate.png").exists()
