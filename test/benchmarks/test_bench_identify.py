# SPDX-License-Identifier: Apache-2.0
"""
Smoke test of the identification benchmark (bench/bench_identify.py) and its trials on the campaign engine.

A tiny run adds up, and the scoring calls a true identification correct and a wrong one
incorrect. The trials (one solver call each) number the setups' solvers and scenes in the old
loop's order; a call's record survives the kind's columns into the same summary; through the
engine on one and on two local workers they are the same records (times aside), the same as
the calls made in this process on the scenes the benchmark draws, and judged against the truth.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_identify as bench  # noqa: E402
from bench.campaign_trials import errors, records, run_trials  # noqa: E402
from bench.peers import PeerSolution  # noqa: E402
from star_tracker.models.attitude import radec_roll_to_matrix, rotation_vector_to_matrix  # noqa: E402
from star_tracker.identify import (Identification, IdentifyConfig, load_or_build_database,  # noqa: E402
                                   make_identifier)
from star_tracker.sim.scenes import SETUPS, make_scene  # noqa: E402

ALGORITHM = "pyramid"  # the example algorithm; the bench itself runs whatever ALGORITHMS holds
TIMING = ("time_s",)  # the columns measured, not computed: they differ between runs


@pytest.fixture(scope="module")
def catalog_now(catalog):
    return catalog.at_epoch(bench.EPOCH_JYEAR)


def engine(workers: int, campaign_output: Path | None = None) -> argparse.Namespace:
    return argparse.Namespace(workers=workers, scheduler=None, campaign_output=campaign_output)


@pytest.fixture(scope="module")
def small_run(catalog_now):
    results = bench.run_benchmark(["nominal", "cole"], [ALGORITHM], scenes=3, seed=5, peers=(),
                                  catalog=catalog_now, log=lambda text: None, engine=engine(2))
    results["meta"]["command"] = "test"
    return results


@pytest.mark.slow  # small_run: a local cluster of 2 workers, ~30 s on a busy 2-core VM
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
    meta = small_run["meta"]
    assert meta["failed_trials"] == 0 and meta["engine_run"]["trials_run"] == 6 and meta["engine_run"]["threads"] == 2
    assert "6 on 2 worker(s)" in meta["engine"]


@pytest.mark.slow  # small_run
def test_report_has_tables(small_run, tmp_path):
    text = bench.render_markdown(small_run)
    assert text.startswith("## Identification")
    assert small_run["meta"]["engine"][1:] in text and "on the worker process that ran it" in text
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


@pytest.mark.slow  # small_run
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


def test_trials_number_the_setups_solvers_and_scenes_in_the_loop_order():
    chosen = {("nominal", "tetra3rs"): "defaults", ("toloei_6_50", "tetra3rs"): "r0.003 t1e-3"}
    options = bench.IdentifyTrials.options({"setups": "nominal,toloei_6_50", "algorithms": "pyramid,hybrid",
                                            "peers": "tetra3rs", "peer_settings": bench.peer_settings_text(chosen),
                                            "scenes": 5, "hard_scenes": 2})
    blocks = options.blocks()
    assert [(b.setup, b.solver, b.peer, b.first_task, b.count) for b in blocks] == [
        ("nominal", "pyramid", False, 0, 5), ("nominal", "hybrid", False, 5, 5), ("nominal", "tetra3rs", True, 10, 5),
        ("toloei_6_50", "pyramid", False, 15, 2), ("toloei_6_50", "hybrid", False, 17, 2),
        ("toloei_6_50", "tetra3rs", True, 19, 2)]
    assert [bench.locate(blocks, t).first_task for t in (0, 4, 5, 14, 15, 20)] == [0, 0, 5, 10, 15, 19]
    for task in (-1, 21):
        with pytest.raises(IndexError):
            bench.locate(blocks, task)
    assert bench.parse_peer_settings(options.peer_settings) == chosen
    config = IdentifyConfig(max_time_s=2.0, max_pattern_spots=20)
    assert bench.IdentifyTrialOptions(identify_config=json.dumps(asdict(config))).config() == config
    assert bench.IdentifyTrialOptions().config() == IdentifyConfig()
    for bad in ({"setups": "nowhere"}, {"algorithms": "guess"}, {"peers": "tetra3rs"},  # no settings for the peer
                {"peers": "tetra3rs", "peer_settings": "nominal:tetra3rs=best"}, {"peer_settings": "nominal"},
                {"scenes": -1}, {"identify_config": '{"max_time_s": -1}'}, {"identify_config": '{"speed": 1}'}):
        with pytest.raises(ValueError):
            bench.IdentifyTrials.options(bad)


def test_a_call_record_survives_the_columns_into_the_same_summary(catalog_now, database):
    scenes = bench.make_scenes(SETUPS["nominal"], catalog_now, 3, seed=5)
    identifier = make_identifier(ALGORITHM, database, IdentifyConfig(max_time_s=2.0))
    calls = [bench.identify_call(identifier, scene) for scene in scenes]
    assert all(c["outcome"] == bench.CORRECT and c["stat_names"] for c in calls)
    rows = [{"task": task, "seed": 5, "error": "", "setup": "nominal", "solver": ALGORITHM, "scene": task,
             "true_stars": scene.real_count, **call} for task, (scene, call) in enumerate(zip(scenes, calls))]
    raised = {"task": 3, "seed": 5, "error": "ValueError: no database",
              **{f.name: None for f in bench.IdentifyTrials.columns}}
    back = records(pa.Table.from_pylist([*rows, raised], schema=bench.IdentifyTrials.schema()))
    direct = bench.Outcomes()
    for call in calls:
        direct.add(call)
    through = bench.block_outcomes(bench.TrialBlock("nominal", ALGORITHM, False, 0, 3), back[:3], scenes)
    assert bench.summarize(through, scenes) == bench.summarize(direct, scenes)

    # A trial that raised in the engine: an inconclusive call with status "error", its text kept.
    failed = bench.summarize(bench.block_outcomes(bench.TrialBlock("nominal", ALGORITHM, False, 3, 1), back[3:],
                                                  scenes[:1]), scenes[:1])
    assert (failed["outcomes"], failed["status"], failed["errors"]) == ("N", {"error": 1}, 1)
    assert failed["first_error"] == "trial raised: ValueError: no database" and failed["time_ms"] is None
    # A record of another scene than this process drew is refused.
    with pytest.raises(RuntimeError, match="other scenes"):
        bench.block_outcomes(bench.TrialBlock("nominal", ALGORITHM, False, 0, 2), back[1:3], scenes)


@pytest.mark.slow  # two local clusters, each worker loading the catalog and two databases: ~1 min on a busy VM
def test_one_and_two_workers_make_the_same_calls_as_this_process(catalog_now, tmp_path):
    peers = [p for p in ("tetra3rs",) if bench.peer_adapters.available()[p] is None]
    setups, algorithms, seed, cache = ["nominal", "cole"], [ALGORITHM, "hybrid"], 5, tmp_path / "peers"
    solvers = {}  # this process's solvers; building them first also fills the caches the workers load from
    for name in setups:
        db_config = bench.database_config(name)
        for algorithm in algorithms:
            solvers[name, algorithm] = make_identifier(algorithm, load_or_build_database(db_config), IdentifyConfig())
        for peer in peers:
            solvers[name, peer] = bench.make_peer(peer, SETUPS[name], db_config, bench.PEER_CANDIDATES[peer][0],
                                                  catalog_now, IdentifyConfig().max_time_s, cache)[0]
    options = bench.IdentifyTrialOptions(
        setups=",".join(setups), algorithms=",".join(algorithms), peers=",".join(peers), scenes=3, seed=seed,
        peer_settings=bench.peer_settings_text({(n, p): bench.PEER_CANDIDATES[p][0].label
                                                for n in setups for p in peers}), peer_cache=str(cache))
    blocks = options.blocks()
    trials = sum(b.count for b in blocks)
    one, run_one = run_trials(bench.IdentifyTrials(), trials, asdict(options), engine(1), seed=seed, batch=2)
    two, run_two = run_trials(bench.IdentifyTrials(), trials, asdict(options), engine(2, tmp_path / "campaign"),
                              seed=seed, batch=2)
    assert errors(one) == errors(two) == []
    assert (run_one["threads"], run_two["threads"]) == (1, 2) and one.num_rows == trials == 6 * (2 + len(peers))
    assert one.drop_columns(list(TIMING)).equals(two.drop_columns(list(TIMING)))
    assert (tmp_path / "campaign" / "bench-identify").is_dir()  # --campaign-output keeps the records

    # The same calls in this process on the scenes the benchmark draws (none near the time limit).
    rows = records(one)
    for block in blocks:
        scenes = bench.make_scenes(SETUPS[block.setup], catalog_now, block.count, seed)
        call = bench.peer_call if block.peer else bench.identify_call
        for index, scene in enumerate(scenes):
            row, here = rows[block.first_task + index], call(solvers[block.setup, block.solver], scene)
            assert (row["setup"], row["solver"], row["scene"], row["true_stars"]) == (
                block.setup, block.solver, index, scene.real_count)
            assert {k: row[k] for k in ("outcome", "stars", "status", "wrong_id", "raised")} == {
                k: here[k] for k in ("outcome", "stars", "status", "wrong_id", "raised")}
            assert list(row["stat_names"]) == here["stat_names"]
            assert np.array_equal(row["stat_values"], here["stat_values"])

    # Truth: ours never names a star wrongly; on the rich 15 deg fields every call is correct.
    ours = [r for r in rows if r["solver"] in algorithms]
    assert not any(r["wrong_id"] for r in ours) and all(r["time_s"] > 0 for r in rows if r["solver"] in algorithms)
    assert all(r["outcome"] == bench.CORRECT for r in ours if r["setup"] == "nominal")
