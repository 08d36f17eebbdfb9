# SPDX-License-Identifier: Apache-2.0
"""
Smoke test of the identification benchmark (bench/bench_identify.py).

A tiny run adds up, and the scoring calls a true identification correct and a wrong one
incorrect.
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_identify as bench  # noqa: E402
from bench.peers import PeerSolution  # noqa: E402
from star_tracker.models.attitude import radec_roll_to_matrix, rotation_vector_to_matrix  # noqa: E402
from star_tracker.identify import Identification, IdentifyConfig, make_identifier  # noqa: E402
from star_tracker.sim.scenes import SETUPS, make_scene  # noqa: E402

ALGORITHM = "pyramid"  # the example algorithm; the bench itself runs whatever ALGORITHMS holds


@pytest.fixture(scope="module")
def catalog_now(catalog):
    return catalog.at_epoch(bench.EPOCH_JYEAR)


@pytest.fixture(scope="module")
def small_run(catalog_now):
    results = bench.run_benchmark(["nominal", "cole"], [ALGORITHM], scenes=3, seed=5, peers=(), catalog=catalog_now,
                                  log=lambda text: None)
    results["meta"]["command"] = "test"
    return results


def test_counts_add_up(small_run):
    assert list(small_run["setups"]) == ["nominal", "cole"]
    for name, entry in small_run["setups"].items():
        s = entry["solvers"][ALGORITHM]
        assert s["scenes"] == entry["scenes"] == 3
        assert s["correct"] + s["inconclusive"] + s["incorrect"] == 3
        assert len(s["outcomes"]) == 3 and sum(s["status"].values()) == 3
        assert s["ge4"]["scenes"] == entry["scenes_ge4_true_stars"]
        assert sum(s["ge4"][k] for k in ("correct", "inconclusive", "incorrect")) == s["ge4"]["scenes"]
        assert s["time_ms"]["median"] <= s["time_ms"]["p99"] <= s["time_ms"]["max"]
    nominal = small_run["setups"]["nominal"]["solvers"][ALGORITHM]
    assert nominal["incorrect"] == 0 and nominal["correct"] >= 2  # rich 15 deg fields
    assert small_run["totals"]["ours"]["calls"] == 6


def test_report_has_tables(small_run, tmp_path):
    text = bench.render_markdown(small_run)
    assert text.startswith("## Identification")
    assert "### cole" in text and "paper: spherical triangle" in text
    assert "Incorrect over all scenes:" in text
    doc = tmp_path / "BENCHMARKS.md"
    doc.write_text("# Benchmarks\n\n## Centroiding\n\nkeep me\n\n## Identification\n\nstale text\n\n## Later\n\n"
                   "keep too\n")
    bench.write_section(doc, text)
    body = doc.read_text()
    assert "stale text" not in body and "keep me" in body and "keep too" in body
    assert body.count("## Identification") == 1
    bench.write_section(doc, text)  # idempotent
    assert doc.read_text() == body


def test_goal_rows_are_judged_from_the_run(small_run):
    """The goal table under Identification: each row's verdict from this run's figures, the peers beside."""
    lines = bench.goals_lines(small_run)
    assert lines[0] == f"### Goals (default algorithm `{small_run['meta']['reference_algorithm']}`)"
    text = "\n".join(lines)
    nominal = small_run["setups"]["nominal"]["solvers"][small_run["meta"]["reference_algorithm"]]
    verdict = "met" if nominal["correct"] == nominal["scenes"] else "**not met**"
    assert f"| nominal: 100 % correct | {nominal['correct_pct']:.1f} % (3 scenes) | {verdict} |" in text
    assert "| ≤ 1 incorrect in 10,000 scenes | 0 in 6 (all our algorithms, all setups) | met |" in text
    assert "toloei" not in text  # setups not run are not judged
    failing = {**small_run, "totals": {**small_run["totals"], "ours": {"incorrect": 2, "calls": 6}}}
    assert "| 2 in 6 (all our algorithms, all setups) | **not met** |" in "\n".join(bench.goals_lines(failing))


def test_scoring_against_truth(catalog_now, database):
    setup = SETUPS["nominal"]
    scene = make_scene(setup, catalog_now, np.random.default_rng(11))
    result = make_identifier(ALGORITHM, database, IdentifyConfig(max_time_s=2.0)).identify(scene.spots, setup.camera)
    assert result.solved and result.hip.size >= 3
    assert bench.score_identification(result, scene) == bench.CORRECT
    shuffled = replace(result, hip=np.roll(result.hip, 1))
    assert bench.score_identification(shuffled, scene) == bench.INCORRECT
    unsolved = Identification(status="no_match", reason="", algorithm=ALGORITHM, elapsed_s=0.0)
    assert bench.score_identification(unsolved, scene) == bench.INCONCLUSIVE


def test_peer_attitude_scoring(catalog_now):
    setup = SETUPS["nominal"]
    truth = radec_roll_to_matrix(1.0, 0.3, 0.2)
    scene = make_scene(setup, catalog_now, np.random.default_rng(3), rotation=truth)

    def solved(rotation):
        return PeerSolution(True, "solved", 0.001, rotation)

    tilt = float(np.radians(2.0 / 60.0))  # 2 arcmin about the sensor x axis
    assert bench.score_attitude(solved(truth), scene) == bench.CORRECT
    assert bench.score_attitude(solved(truth @ rotation_vector_to_matrix(np.array([tilt, 0, 0]))),
                                scene) == bench.INCORRECT
    assert bench.score_attitude(solved(truth @ rotation_vector_to_matrix(np.array([0, 0, 0.005]))),
                                scene) == bench.CORRECT
    assert bench.score_attitude(solved(truth @ rotation_vector_to_matrix(np.array([0, 0, 0.05]))),
                                scene) == bench.INCORRECT
    assert bench.score_attitude(PeerSolution(False, "no_match", 0.001), scene) == bench.INCONCLUSIVE
    assert bench.score_attitude(PeerSolution(True, "parity_flip", 0.001), scene) == bench.INCORRECT


def test_tetra3rs_adapter_conventions(catalog_now, tmp_path):
    """The peer's attitude and ids, converted to ours, match the truth (when installed)."""
    pytest.importorskip("tetra3rs")
    setup = SETUPS["nominal"]
    scene = make_scene(setup, catalog_now, np.random.default_rng(21))
    solver, _, _ = bench.make_peer("tetra3rs", setup, bench.database_config("nominal"), bench.PeerCandidate("defaults"),
                                   catalog_now, 0.5, tmp_path)
    solution = solver.solve(scene.spots.x, scene.spots.y)
    assert bench.score_attitude(solution, scene) == bench.CORRECT
    boresight, _ = bench.attitude_errors(solution.rotation, scene.rotation)
    assert boresight < np.radians(20.0 / 3600.0)
    assert solution.ids.size >= 10 and np.mean(solution.ids == scene.hip[solution.spot_index]) > 0.9
