# SPDX-License-Identifier: Apache-2.0
"""
Star-identification benchmark: our algorithms and two peer solvers on identical centroid lists.

    python -m bench.bench_identify [--scenes N] [--setups a,b] [--algorithms a,b] [--no-peers]
                                   [--output docs/BENCHMARKS.md] [--seed S]
                                   [--workers N | --scheduler tcp://HOST:8786] [--campaign-output DIR]

Scenes: for every setup of `star_tracker.sim.scenes.SETUPS` (the seed papers' test cases) N scenes
with random attitudes are drawn from a fixed seed (numpy Generator seeded with (seed, setup
name)); every solver gets the same centroid lists. Setups where every call runs to the time
limit (HARD_SETUPS) use at most --hard-scenes of them, the first ones of the same list.

Our algorithms: every entry of `star_tracker.identify.ALGORITHMS` (or --algorithms), each with
the per-setup database of DATABASE_CONFIGS and the default IdentifyConfig (max_time_s 0.5 s).
A result is correct when it is solved and every returned HIP id is the truth behind its spot,
incorrect when solved with any wrong id, inconclusive otherwise. Time: time.perf_counter()
around identify().

Peers (bench/peers.py, optional, requirements-bench.txt): tetra3rs and cedar-solve, with
pattern databases generated from the same guide stars (Hipparcos at the scene epoch, Hp, the
setup's magnitude limit) for the setup's field of view, cached under
<cache>/bench_peers. Each peer tries the candidate settings of PEER_CANDIDATES on a separate
tuning set of scenes (another seed) and keeps the best (most correct minus 10x incorrect;
then fewest wrong ids; then the faster). A peer result is correct when its boresight is within
1 arcmin of the truth and its roll about the boresight within 1 deg (a gross check: a wrong
identification is off by degrees, while the roll of a correct sparse-field solution can be off
by arcminutes); the star ids it returns are checked against the truth as well (column "wrong
id"). Time: the solve call alone, same time limit as ours.

How the calls run: the peers' tuning is a loop in this process (it picks the settings before
anything is measured). Every measured call is then one trial of the campaign engine
(bench/campaign_trials.py; kind `bench-identify`, IdentifyTrials): a trial is one (setup,
solver, scene) call, in the order of the old loop (per setup: each algorithm, then each peer
with the settings tuning kept, over the setup's scenes). The trials run on a local Dask cluster
of --workers processes (default: every core), or on the cluster at --scheduler; with
--campaign-output DIR their records stay in DIR/bench-identify (Parquet) and an interrupted run
resumes there, with the peer settings and tuning table of the interrupted run (kept in
DIR/bench-identify-tuning.json: a tuning's tie goes to the faster candidate, so a second tuning
could choose otherwise). A worker process builds each setup's scenes (the same seed), our
database and identifier or the peer's solver once, and makes untimed warm-up calls on the first
scene before its first timed call (until one ends within the time limit: a first call that loads
the compiled kernels on a busy host can run out of time and leave later code cold), so every
timed call is warm; each call is timed on the worker that ran it (the local workers run side by
side). The records come back in task order, so the figures other than the times do not depend on
the workers; a trial that raised is counted (inconclusive, status "error") and reported.

Output: the "## Identification" section of --output (the rest of the file is kept) and the raw
numbers as JSON (bench_identify.json beside it, or --json).
"""
from __future__ import annotations

import argparse
import bisect
import dataclasses
import datetime as dt
import json
import os
import platform
import shlex
import sys
import time
import zlib
from dataclasses import replace, dataclass, field
from importlib import metadata
from pathlib import Path

import numpy as np
import pyarrow as pa

from star_tracker.models.catalog import StarCatalog, cache_dir, load_hipparcos
from star_tracker.commands.bench import report_progress
from star_tracker.identify import (ALGORITHMS, DEFAULT_ALGORITHM, DatabaseConfig, Identification, IdentifyConfig,
                                   load_or_build_database, make_identifier)
from star_tracker.campaign import CampaignKind
from star_tracker.sim.scenes import SETUPS, Scene, SceneSetup, make_scene

from . import peers as peer_adapters
from .campaign_trials import add_engine_arguments, engine_line, errors, records, run_trials
from .machine import cpu_model
from .report import write_section

EPOCH_JYEAR = 2026.0
DEFAULT_SEED = 2026
ARCMIN_RAD = float(np.radians(1.0 / 60.0))
BORESIGHT_TOLERANCE_RAD = ARCMIN_RAD  # peer attitude: cross-boresight error for "correct"
ROLL_TOLERANCE_RAD = float(np.radians(1.0))  # peer attitude: gross roll check
PAIR_MARGIN_RAD = float(np.radians(0.2))  # pair database reach beyond the field diameter

# Per-setup pattern database (guide stars and largest pair angle); others use the default.
DATABASE_CONFIGS: dict[str, DatabaseConfig] = {
    "cole": DatabaseConfig(magnitude_limit=6.0, max_pair_angle_rad=float(np.radians(8.0)) + PAIR_MARGIN_RAD),
    "cole_false": DatabaseConfig(magnitude_limit=6.0, max_pair_angle_rad=float(np.radians(8.0)) + PAIR_MARGIN_RAD),
    # The scenes' own limit: at 6.5 a few brightest-8 lists hold only 4 guide stars.
    "fast": DatabaseConfig(magnitude_limit=7.0, max_pair_angle_rad=float(np.radians(11.3)) + PAIR_MARGIN_RAD),
}
# Setups where most calls of most solvers run to the time limit: fewer scenes, and fewer
# scenes to tune the peers on.
HARD_SETUPS = ("toloei_6_50", "toloei_4_136")
HARD_TUNE_SCENES = 20
# Toloei's method forms patterns from every spot, not just the brightest few: on these setups
# all algorithms may use up to 100 spots for patterns.
SETUP_IDENTIFY_OVERRIDES: dict[str, dict] = {name: {"max_pattern_spots": 100} for name in HARD_SETUPS}
# Setups reported with the split over scenes with >= 4 true stars (Cole & Crassidis).
SPLIT_SETUPS = ("cole", "cole_false")

# The papers' own numbers, shown under our rows.
PAPER_ROWS: dict[str, list[tuple[str, str]]] = {
    "cole": [
        ("paper: angle method, 9 pivots (Cole & Crassidis Table 2)",
         "55 % correct, 45 % inconclusive, < 1 % incorrect; 4.86 pivots, 6.86 stars; 6.89 s average (2004 CPU)"),
        ("paper: spherical triangle, 3 pivots (Table 2)",
         "92 % correct (scenes with >= 4 stars), 6 % inconclusive, < 1 % incorrect; 1.29 pivots, 4.29 stars; "
         "1.65 s average"),
    ],
    "cole_false": [
        ("paper: angle method with a false star (Table 2)", "25 % correct, 59 % inconclusive, 17 % incorrect"),
        ("paper: spherical triangle with a false star (Table 2)", "52 % correct, 36 % inconclusive, 10 % incorrect"),
    ],
    "fast": [
        ("paper: FAST, van Bezooijen (expected)",
         "98.2 % success (99.3 % with a 10-magnitude dynamic range); failures from the dynamic range and from "
         "fields with < 3-4 guide stars"),
    ],
}


@dataclass(frozen=True)
class PeerCandidate:
    """
    One peer configuration.

    Label, database generator keywords beyond FOV and magnitude limit, solve keywords beyond
    FOV, FOV tolerance and time limit.
    """

    label: str
    database: dict = field(default_factory=dict)
    solve: dict = field(default_factory=dict)


# Few candidates per peer, chosen from a sweep of match radius (fraction of the FOV), match
# threshold (false-positive budget) and pattern tolerance (edge-ratio error): the peers'
# defaults, a tight radius with a relaxed threshold (sparse fields), and that plus a wider
# pattern tolerance (noisy fields such as Cole's 87 urad).
PEER_CANDIDATES: dict[str, list[PeerCandidate]] = {
    "tetra3rs": [
        PeerCandidate("defaults"),
        PeerCandidate("r0.003 t1e-3", solve=dict(match_radius=0.003, match_threshold=1e-3)),
        PeerCandidate("r0.003 t1e-3 e0.003",
                      solve=dict(match_radius=0.003, match_threshold=1e-3, match_max_error=0.003)),
    ],
    "cedar-solve": [
        PeerCandidate("defaults"),
        PeerCandidate("r0.003 t1e-2", solve=dict(match_radius=0.003, match_threshold=1e-2)),
        PeerCandidate("r0.003 t1e-2 e0.005",
                      solve=dict(match_radius=0.003, match_threshold=1e-2, match_max_error=0.005)),
    ],
}


def database_config(setup_name: str) -> DatabaseConfig:
    return DATABASE_CONFIGS.get(setup_name, DatabaseConfig())


def make_scenes(setup: SceneSetup, catalog: StarCatalog, count: int, seed: int, stream: int = 0) -> list[Scene]:
    """
    `count` scenes of `setup` from a generator seeded by (seed, setup name, stream).

    Stream 0 is the benchmark set, 1 the peers' tuning set.
    """
    rng = np.random.default_rng([seed, zlib.crc32(setup.name.encode()), stream])
    return [make_scene(setup, catalog, rng) for _ in range(count)]


# ----------------------------------------------------------------------------- scoring

CORRECT, INCONCLUSIVE, INCORRECT = "correct", "inconclusive", "incorrect"
_CODE = {CORRECT: "C", INCONCLUSIVE: "N", INCORRECT: "I"}


def score_identification(result: Identification, scene: Scene) -> str:
    """Ours: correct = solved and every returned HIP id equals the truth behind its spot."""
    if not result.solved:
        return INCONCLUSIVE
    truth = scene.hip[np.asarray(result.spot_index, np.int64)]
    return CORRECT if np.array_equal(np.asarray(result.hip, np.int64), truth) else INCORRECT


def attitude_errors(rotation: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(cross-boresight, roll) errors [rad] of a sensor->ICRS rotation against the truth."""
    z, z_true = rotation[:, 2], truth[:, 2]
    boresight = float(np.arctan2(np.linalg.norm(np.cross(z, z_true)), z @ z_true))
    # Roll: the solved x axis seen in the true sensor frame, angle about +z.
    x_in_truth = truth.T @ rotation[:, 0]
    roll = float(abs(np.arctan2(x_in_truth[1], x_in_truth[0])))
    return boresight, roll


def score_attitude(solution: peer_adapters.PeerSolution, scene: Scene) -> str:
    """Peers: correct = boresight within 1 arcmin and roll within 1 deg of the truth."""
    if not solution.solved:
        return INCONCLUSIVE
    if solution.rotation is None:  # e.g. a mirror-image solution
        return INCORRECT
    boresight, roll = attitude_errors(solution.rotation, scene.rotation)
    return CORRECT if boresight <= BORESIGHT_TOLERANCE_RAD and roll <= ROLL_TOLERANCE_RAD else INCORRECT


def peer_ids_wrong(solution: peer_adapters.PeerSolution, scene: Scene) -> bool:
    """Return a solved peer result that named any spot with a star other than the truth."""
    if not solution.solved or solution.ids.size == 0:
        return False
    return not np.array_equal(solution.ids, scene.hip[solution.spot_index])


# ----------------------------------------------------------------------------- one call


def call_record(outcome: str, elapsed_s: float, stars: int, status: str, stats: dict | None = None,
                wrong_id: bool = False, raised: str = "") -> dict:
    """
    Return one solver call as a record (the kind's columns after setup, solver, scene and true_stars).

    elapsed_s: the call's wall time [s] (NaN when a peer raised); stats: the identifier's numeric
    counters (booleans and non-numbers left out), as parallel name and value lists; raised: the
    exception text of a call that raised ("" otherwise).
    """
    numeric = {k: float(v) for k, v in (stats or {}).items()
               if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)}
    return {"outcome": outcome, "time_s": float(elapsed_s), "stars": int(stars), "status": status,
            "stat_names": list(numeric), "stat_values": list(numeric.values()), "wrong_id": bool(wrong_id),
            "raised": raised}


def identify_call(identifier, scene: Scene) -> dict:
    """Run ours on one scene: time.perf_counter() around identify(); a call that raises is inconclusive."""
    started = time.perf_counter()
    try:
        result = identifier.identify(scene.spots, scene.setup.camera)
    except Exception as exc:  # noqa: BLE001 - one failing call must not end a long run; it is reported
        return call_record(INCONCLUSIVE, time.perf_counter() - started, 0, "error",
                           raised=f"{type(exc).__name__}: {exc}")
    elapsed = time.perf_counter() - started
    outcome = score_identification(result, scene)
    return call_record(outcome, elapsed, int(result.hip.size) if result.solved else 0, result.status, result.stats,
                       wrong_id=outcome == INCORRECT)


def peer_call(solver, scene: Scene) -> dict:
    """Run a peer on one scene: the adapter times the solve call alone; a call that raises is inconclusive."""
    try:
        solution = solver.solve(scene.spots.x, scene.spots.y)
    except Exception as exc:  # noqa: BLE001 - as in identify_call
        return call_record(INCONCLUSIVE, float("nan"), 0, "error", raised=f"{type(exc).__name__}: {exc}")
    return call_record(score_attitude(solution, scene), solution.elapsed_s,
                       int(solution.ids.size) if solution.solved else 0, solution.status,
                       wrong_id=peer_ids_wrong(solution, scene))


# Untimed calls before the timed ones: compiled kernels load from numba's cache on first use, in
# each process. On a busy host that loading can take the first call past its time limit, and the
# code after the point where it stopped stays cold: so call again until a call ends in time.
WARM_UP_CALLS = 3


def warm_up(call, solver, scenes: list[Scene]) -> None:
    """Make untimed calls on the first scene until one ends within the time limit (at most WARM_UP_CALLS)."""
    for _ in range(WARM_UP_CALLS if scenes else 0):
        if "timeout" not in call(solver, scenes[0])["status"].lower():  # never raises: a failing call is a record
            break


# ----------------------------------------------------------------------------- running in this process (the tuning)


@dataclass
class Outcomes:
    """Per-scene results of one solver on one setup."""

    outcome: list[str] = field(default_factory=list)
    time_s: list[float] = field(default_factory=list)
    stars: list[int] = field(default_factory=list)
    status: dict[str, int] = field(default_factory=dict)
    stats: dict[str, list[float]] = field(default_factory=dict)
    wrong_ids: int = 0
    errors: list[str] = field(default_factory=list)

    def add(self, record: dict) -> None:
        """Add one call's record (call_record's keys; list columns as lists or numpy arrays)."""
        self.outcome.append(record["outcome"])
        self.time_s.append(record["time_s"])
        self.stars.append(record["stars"])
        self.status[record["status"]] = self.status.get(record["status"], 0) + 1
        for key, value in zip(record["stat_names"], record["stat_values"]):
            self.stats.setdefault(str(key), []).append(float(value))
        self.wrong_ids += bool(record["wrong_id"])
        if record["raised"]:
            self.errors.append(record["raised"])


def run_peer(solver, scenes: list[Scene], on_scene=None) -> Outcomes:
    """
    Run a peer over scenes in this process, after untimed warm-up calls (the tuning, tune_peer).

    on_scene(): called after each call (progress reporting).
    """
    out = Outcomes()
    warm_up(peer_call, solver, scenes)
    for scene in scenes:
        out.add(peer_call(solver, scene))
        if on_scene is not None:
            on_scene()
    return out


def summarize(out: Outcomes, scenes: list[Scene]) -> dict:
    """Return counts, percentages, means and time quantiles [ms] of one solver on one setup."""
    n = len(out.outcome)
    codes = np.array(out.outcome)
    times = np.array(out.time_s, float) * 1e3
    times = times[np.isfinite(times)]
    solved = np.array([o != INCONCLUSIVE for o in out.outcome])
    stars = np.array(out.stars, float)
    summary = {
        "scenes": n,
        "correct": int(np.sum(codes == CORRECT)),
        "inconclusive": int(np.sum(codes == INCONCLUSIVE)),
        "incorrect": int(np.sum(codes == INCORRECT)),
        "wrong_ids": int(out.wrong_ids),
        "errors": len(out.errors),
        "first_error": out.errors[0] if out.errors else None,
        "status": dict(sorted(out.status.items())),
        "stars_used_mean": float(stars[solved].mean()) if solved.any() else None,
        "stats_mean": {k: float(np.mean(v)) for k, v in sorted(out.stats.items())},
        "time_ms": {"median": float(np.median(times)), "p99": float(np.percentile(times, 99)),
                    "max": float(times.max()), "mean": float(times.mean())} if times.size else None,
        # The distribution for bench/plots.py: percentiles 0, 1, ..., 100 [ms].
        "time_ms_percentiles": ([float(f"{v:.5g}") for v in np.percentile(times, np.arange(101))]
                                if times.size else None),
        "outcomes": "".join(_CODE[o] for o in out.outcome),
    }
    for key in (CORRECT, INCONCLUSIVE, INCORRECT):
        summary[f"{key}_pct"] = 100.0 * summary[key] / n if n else float("nan")
    real = np.array([s.real_count for s in scenes[:n]])
    rich = real >= 4
    summary["ge4"] = {"scenes": int(rich.sum()), **{key: int(np.sum(codes[rich] == key)) for key in
                                                    (CORRECT, INCONCLUSIVE, INCORRECT)}}
    return summary


def make_peer(peer: str, setup: SceneSetup, db_config: DatabaseConfig, candidate: PeerCandidate,
              catalog: StarCatalog, max_time_s: float, cache: Path):
    """
    Return the peer adapter for a setup.

    Database for the camera's horizontal FOV and our guide stars' magnitude limit, FOV known
    to 0.1 deg, the same time limit as ours.
    """
    camera = setup.camera
    fov_deg = float(np.degrees(2.0 * np.arctan(0.5 * camera.width / camera.fx)))
    stars = catalog.brighter_than(db_config.magnitude_limit)
    peer_catalog = peer_adapters.PeerCatalog(stars.hip.astype(np.int64), stars.ra, stars.dec, stars.hp)
    peer_camera = peer_adapters.PeerCamera(camera.width, camera.height, fov_deg)
    timeout_ms = int(round(1000 * max_time_s))
    if peer == "tetra3rs":
        database = dict(max_fov_deg=fov_deg, star_max_magnitude=db_config.magnitude_limit,
                        epoch_proper_motion_year=EPOCH_JYEAR, **candidate.database)
        solve = dict(fov_max_error_deg=0.1, solve_timeout_ms=timeout_ms, **candidate.solve)
        return peer_adapters.Tetra3rsSolver(peer_catalog, peer_camera, database, solve, cache), database, solve
    if peer == "cedar-solve":
        database = dict(max_fov=fov_deg, star_max_magnitude=db_config.magnitude_limit, **candidate.database)
        solve = dict(fov_max_error=0.1, solve_timeout=timeout_ms, distortion=0, **candidate.solve)
        return peer_adapters.CedarSolver(peer_catalog, peer_camera, database, solve, cache), database, solve
    raise ValueError(f"unknown peer {peer!r}")


def tune_peer(peer: str, setup: SceneSetup, db_config: DatabaseConfig, catalog: StarCatalog, tuning: list[Scene],
              max_time_s: float, cache: Path, log,
              on_scene=None) -> tuple[object, PeerCandidate, dict, dict, list[dict]]:
    """
    Try every candidate on the tuning scenes.

    Keep the best (correct - 10 incorrect, then fewer wrong ids, then the lower median
    time). Returns (solver, candidate, database kw, solve kw, trials).
    """
    best, trials = None, []
    for candidate in PEER_CANDIDATES[peer]:
        solver, database, solve = make_peer(peer, setup, db_config, candidate, catalog, max_time_s, cache)
        s = summarize(run_peer(solver, tuning, on_scene), tuning) if tuning else None
        score = (s["correct"] - 10 * s["incorrect"], -s["wrong_ids"], -s["time_ms"]["median"]) if s else (0, 0, 0)
        trials.append({"label": candidate.label, "solve": solve, "database": database,
                       **({k: s[k] for k in ("scenes", "correct", "inconclusive", "incorrect", "wrong_ids")}
                          if s else {}), "median_ms": s["time_ms"]["median"] if s else None})
        log(f"  {peer} tuning {candidate.label}: {trials[-1]}")
        if best is None or score > best[0]:
            best = (score, solver, candidate, database, solve)
        if not tuning:
            break
    return best[1], best[2], best[3], best[4], trials


# ----------------------------------------------------------------------------- the measured calls: campaign engine


def setup_scene_count(name: str, scenes: int, hard_scenes: int) -> int:
    """Return the scenes of setup `name`: --scenes, at most --hard-scenes on HARD_SETUPS."""
    return min(scenes, hard_scenes) if name in HARD_SETUPS else scenes


def _split(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def peer_settings_text(chosen: dict[tuple[str, str], str]) -> str:
    """Return the settings tuning kept as an option: "setup:peer=label;..." (labels of PEER_CANDIDATES)."""
    return ";".join(f"{setup}:{peer}={label}" for (setup, peer), label in chosen.items())


def parse_peer_settings(text: str) -> dict[tuple[str, str], str]:
    """Return {(setup, peer): candidate label} from peer_settings_text's form; malformed text raises ValueError."""
    chosen = {}
    for part in filter(None, (p.strip() for p in text.split(";"))):
        key, sep, label = part.partition("=")
        setup, colon, peer = key.partition(":")
        if not sep or not colon:
            raise ValueError(f"peer setting {part!r}: expected setup:peer=label")
        chosen[(setup.strip(), peer.strip())] = label.strip()
    return chosen


@dataclass(frozen=True)
class IdentifyTrialOptions:
    """
    What the trials of one benchmark run are (plain scalars, so the engine can ship and compare them).

    setups, algorithms, peers: comma-separated names (SETUPS, ALGORITHMS, PEER_CANDIDATES), in
    the report's order; peer_settings: the candidate tuning kept per setup and peer
    (peer_settings_text); scenes, hard_scenes: scenes per setup (setup_scene_count); seed: the
    scenes' seed (make_scenes); identify_config: the IdentifyConfig as JSON ("" = the
    default); peer_cache: the peers' database cache ("" = <cache>/bench_peers of the worker).
    """

    setups: str = "nominal"
    algorithms: str = DEFAULT_ALGORITHM
    peers: str = ""
    peer_settings: str = ""
    scenes: int = 1000
    hard_scenes: int = 100
    seed: int = DEFAULT_SEED
    identify_config: str = ""
    peer_cache: str = ""

    def __post_init__(self) -> None:
        bad = [f"{what} {name!r} unknown; choose from {', '.join(known)}"
               for what, text, known in (("setup", self.setups, SETUPS), ("algorithm", self.algorithms, ALGORITHMS),
                                         ("peer", self.peers, PEER_CANDIDATES))
               for name in _split(text) if name not in known]
        if self.scenes < 0 or self.hard_scenes < 0:
            bad.append(f"scenes ({self.scenes}) and hard_scenes ({self.hard_scenes}) must be >= 0")
        try:
            chosen = parse_peer_settings(self.peer_settings)
            self.config()
        except (ValueError, TypeError) as exc:
            bad.append(str(exc))
            chosen = {}
        for setup in _split(self.setups):
            for peer in _split(self.peers):
                label = chosen.get((setup, peer))
                if label not in [c.label for c in PEER_CANDIDATES.get(peer, [])]:
                    bad.append(f"peer_settings: {setup}:{peer} is {label!r}, not a label of PEER_CANDIDATES[{peer!r}]")
        if bad:
            raise ValueError("bench-identify options: " + "; ".join(bad))

    def config(self) -> IdentifyConfig:
        return IdentifyConfig(**json.loads(self.identify_config)) if self.identify_config else IdentifyConfig()

    def blocks(self) -> list["TrialBlock"]:
        """Return the trials in task order: per setup, each algorithm then each peer, over the setup's scenes."""
        blocks, first = [], 0
        for setup in _split(self.setups):
            count = setup_scene_count(setup, self.scenes, self.hard_scenes)
            for solver, peer in [(a, False) for a in _split(self.algorithms)] + [(p, True) for p in _split(self.peers)]:
                blocks.append(TrialBlock(setup, solver, peer, first, count))
                first += count
        return blocks


@dataclass(frozen=True)
class TrialBlock:
    """One solver's calls on one setup: tasks first_task .. first_task + count - 1, scene i = task - first_task."""

    setup: str
    solver: str
    peer: bool
    first_task: int
    count: int


def locate(blocks: list[TrialBlock], task: int, starts: list[int] | None = None) -> TrialBlock:
    """Return the block that holds trial `task` (starts: the blocks' first tasks, when at hand)."""
    starts = starts if starts is not None else [b.first_task for b in blocks]
    index = bisect.bisect_right(starts, task) - 1
    if task < 0 or index < 0 or task - blocks[index].first_task >= blocks[index].count:
        total = blocks[-1].first_task + blocks[-1].count if blocks else 0
        raise IndexError(f"task {task} is not one of the {total} trials")
    return blocks[index]


class IdentifyWorker:
    """
    Per worker process: the catalog, each setup's scenes, and each (setup, solver) ready and warm.

    Built on a block's first trial in this process, then kept for the process's life (a worker
    may run any block): our database per setup (shared by the algorithms) and identifier, or
    the peer's solver with the settings tuning chose; each followed by untimed warm-up calls
    on the setup's first scene (warm_up), so every timed call is warm.
    """

    def __init__(self, options: IdentifyTrialOptions):
        self.options = options
        self.config = options.config()
        self.catalog = load_hipparcos().at_epoch(EPOCH_JYEAR)
        self.cache = Path(options.peer_cache) if options.peer_cache else cache_dir() / "bench_peers"
        self.chosen = parse_peer_settings(options.peer_settings)
        self.blocks = options.blocks()
        self.starts = [b.first_task for b in self.blocks]
        self._scenes: dict[str, list[Scene]] = {}
        self._databases: dict[str, object] = {}  # repr(DatabaseConfig) -> database
        self._solvers: dict[tuple[str, str], object] = {}

    def block(self, task: int) -> TrialBlock:
        return locate(self.blocks, task, self.starts)

    def scenes(self, setup: str) -> list[Scene]:
        """Return the setup's benchmark scenes, drawn as the in-process run drew them (make_scenes, stream 0)."""
        if setup not in self._scenes:
            count = setup_scene_count(setup, self.options.scenes, self.options.hard_scenes)
            self._scenes[setup] = make_scenes(SETUPS[setup], self.catalog, count, self.options.seed)
        return self._scenes[setup]

    def solver(self, block: TrialBlock):
        """Return the block's identifier or peer solver, built and warmed up on first use."""
        key = (block.setup, block.solver)
        if key not in self._solvers:
            setup, db_config = SETUPS[block.setup], database_config(block.setup)
            if block.peer:
                label = self.chosen[key]
                candidate = next(c for c in PEER_CANDIDATES[block.solver] if c.label == label)
                solver = make_peer(block.solver, setup, db_config, candidate, self.catalog, self.config.max_time_s,
                                   self.cache)[0]
            else:
                if repr(db_config) not in self._databases:
                    self._databases[repr(db_config)] = load_or_build_database(db_config)
                setup_config = replace(self.config, **SETUP_IDENTIFY_OVERRIDES.get(block.setup, {}))
                solver = make_identifier(block.solver, self._databases[repr(db_config)], setup_config)
            warm_up(peer_call if block.peer else identify_call, solver, self.scenes(block.setup))
            self._solvers[key] = solver
        return self._solvers[key]


class IdentifyTrials(CampaignKind):
    """
    One trial = one solver call: (setup, solver, scene) of the benchmark's loop, in its order (TrialBlock).

    The scene is the one the in-process benchmark drew (make_scenes from the options' seed), so
    the engine's per-trial generator is not used. The call is timed on the worker that ran it,
    warm (IdentifyWorker).
    """

    name = "bench-identify"
    description = "bench_identify: our algorithms and the peers on the seed papers' setups, one call per trial"
    options_type = IdentifyTrialOptions
    default_trials = 1000  # the default options: nominal, the default algorithm
    # ~2 ms a call on most setups (0.1 s a batch), up to the 0.5 s time limit on HARD_SETUPS (25 s)
    default_batch = 50
    columns = (pa.field("setup", pa.string()), pa.field("solver", pa.string()), pa.field("scene", pa.int64()),
               pa.field("true_stars", pa.int64()), pa.field("outcome", pa.string()), pa.field("time_s", pa.float64()),
               pa.field("stars", pa.int64()), pa.field("status", pa.string()),
               pa.field("stat_names", pa.list_(pa.string())), pa.field("stat_values", pa.list_(pa.float64())),
               pa.field("wrong_id", pa.bool_()), pa.field("raised", pa.string()))

    def prepare(self, options: IdentifyTrialOptions) -> IdentifyWorker:
        return IdentifyWorker(options)

    def trial(self, shared: IdentifyWorker, options: IdentifyTrialOptions, task: int,
              rng: np.random.Generator) -> dict:
        block = shared.block(task)
        solver = shared.solver(block)
        scene = shared.scenes(block.setup)[task - block.first_task]
        record = (peer_call if block.peer else identify_call)(solver, scene)
        return {"setup": block.setup, "solver": block.solver, "scene": task - block.first_task,
                "true_stars": scene.real_count, **record}

    def summarize(self, table: pa.Table, options: IdentifyTrialOptions) -> dict:
        return {}  # the benchmark's own summarize() makes the figures


def block_outcomes(block: TrialBlock, rows: list[dict], scenes: list[Scene]) -> Outcomes:
    """
    Return one block's Outcomes from its records (task order).

    A trial that raised in the engine (its columns empty) is an inconclusive call with status
    "error" and the engine's error text, as a call that raised; a record of another scene than
    this process drew (a worker with another catalog) raises.
    """
    out = Outcomes()
    for index, row in enumerate(rows):
        if row["error"]:
            out.add(call_record(INCONCLUSIVE, float("nan"), 0, "error", raised=f"trial raised: {row['error']}"))
            continue
        if (row["setup"], row["solver"], row["scene"], row["true_stars"]) != (
                block.setup, block.solver, index, scenes[index].real_count):
            raise RuntimeError(f"task {row['task']}: record of {row['setup']}/{row['solver']} scene {row['scene']} "
                               f"({row['true_stars']} true stars), expected {block.setup}/{block.solver} scene "
                               f"{index} ({scenes[index].real_count}): the workers drew other scenes")
        out.add(row)
    return out


TUNING_FILE = "bench-identify-tuning.json"  # in --campaign-output: the peers' tuning, for a resumed run


def saved_tuning(path: Path | None, key: dict) -> dict[tuple[str, str], dict]:
    """Return the peers' tuning a run with the same key saved at path ({} when none or another run's)."""
    if path is None or not path.is_file():
        return {}
    saved = json.loads(path.read_text())
    if saved.get("key") != key:
        return {}
    return {tuple(name.split(":", 1)): entry for name, entry in saved["tuned"].items()}


def save_tuning(path: Path, key: dict, tuned: dict[tuple[str, str], dict]) -> None:
    """Keep the peers' tuning (settings kept, table, database figures) beside the records, for a resumed run."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"key": key, "tuned": {f"{setup}:{peer}": entry for (setup, peer), entry
                                                      in tuned.items()}}, indent=1, default=float) + "\n")


def run_benchmark(setup_names: list[str], algorithms: list[str], scenes: int, seed: int = DEFAULT_SEED,
                  peers: list[str] = (), tune_scenes: int = 100, hard_scenes: int = 100,
                  catalog: StarCatalog | None = None, cache: Path | None = None,
                  config: IdentifyConfig | None = None, log=print, progress=None,
                  engine: argparse.Namespace | None = None) -> dict:
    """
    Run every solver on every setup; returns the JSON-ready results (see module docstring).

    The peers' tuning runs here, in this process (it chooses the settings before the measured
    calls); then every measured call is one trial on the campaign engine (IdentifyTrials;
    engine: the parsed --workers/--scheduler/--campaign-output, None = a local cluster on
    every core). catalog: Hipparcos at EPOCH_JYEAR (the workers load that one themselves);
    cache: the peers' databases (default <cache>/bench_peers, the workers' own when None).
    progress(done, total, note): after every tuning call, and as the engine reports trials.
    """
    run_started = time.perf_counter()
    catalog = catalog if catalog is not None else load_hipparcos().at_epoch(EPOCH_JYEAR)
    peer_cache = cache if cache is not None else cache_dir() / "bench_peers"
    config = config or IdentifyConfig()
    counts = {name: setup_scene_count(name, scenes, hard_scenes) for name in setup_names}
    tune_counts = {name: min(tune_scenes, count, HARD_TUNE_SCENES if name in HARD_SETUPS else count)
                   for name, count in counts.items()}
    calls_total = sum(len(PEER_CANDIDATES[p]) * tune_counts[name] for name in setup_names for p in peers)
    calls_total += sum(counts.values()) * (len(algorithms) + len(peers))
    calls = [0, ""]

    def tick() -> None:
        calls[0] += 1
        if progress is not None:
            progress(calls[0], calls_total, calls[1])

    entries, scene_lists, tuned = {}, {}, {}
    for name in setup_names:
        setup = SETUPS[name]
        scene_list = scene_lists[name] = make_scenes(setup, catalog, counts[name], seed)
        real = np.array([s.real_count for s in scene_list])
        db_config = database_config(name)
        database = load_or_build_database(db_config)  # built here once, so the workers load it from the cache
        count = counts[name]
        entries[name] = {
            "description": setup.description, "scenes": count,
            "true_stars_mean": float(real.mean()) if count else None,
            "scenes_ge4_true_stars": int(np.sum(real >= 4)),
            "real_stars": setup.real_stars, "false_stars": setup.false_stars,
            "spots_mean": float(np.mean([len(s.spots) for s in scene_list])) if count else None,
            "database": {"magnitude_limit": db_config.magnitude_limit,
                         "max_pair_angle_deg": float(np.degrees(db_config.max_pair_angle_rad)),
                         "stars": database.star_count, "pairs": int(database.pair_a.size),
                         "build_seconds": float(database.build_seconds)},
            "solvers": {},
            "identify_overrides": SETUP_IDENTIFY_OVERRIDES.get(name, {}),
        }
        del database

    # The peers' tuning stays a loop in this process: it picks the settings the measured trials then use
    # (a tie goes to the faster, so two tunings may differ). A resumed run takes the interrupted one's.
    identify_config = "" if config == IdentifyConfig() else json.dumps(dataclasses.asdict(config))
    tuning_key = {"setups": list(setup_names), "peers": list(peers), "scenes": scenes, "hard_scenes": hard_scenes,
                  "tune_scenes": tune_scenes, "seed": seed, "identify_config": identify_config,
                  "versions": {peer: metadata.version(peer) for peer in peers}}
    tuning_file = Path(engine.campaign_output) / TUNING_FILE if getattr(engine, "campaign_output", None) else None
    tuned = saved_tuning(tuning_file, tuning_key) if peers else {}
    if tuned:
        log(f"peer settings and tuning table from {tuning_file} (the run resumed)")
        calls[0] += sum(len(PEER_CANDIDATES[p]) * tune_counts[name] for name in setup_names for p in peers)
    elif peers:
        for name in setup_names:
            setup, db_config = SETUPS[name], database_config(name)
            tuning = make_scenes(setup, catalog, tune_counts[name], seed, stream=1)
            for peer in peers:
                calls[1] = f"{name}: {peer} (tuning)"
                solver, candidate, database_kw, solve_kw, trials = tune_peer(
                    peer, setup, db_config, catalog, tuning, config.max_time_s, peer_cache, log, tick)
                calls[0] += (len(PEER_CANDIDATES[peer]) - len(trials)) * len(tuning)  # candidates not tried
                tuned[(name, peer)] = {
                    "kind": "peer", "version": metadata.version(peer), "settings": candidate.label,
                    "database_settings": database_kw, "solve_settings": solve_kw, "tuning": trials,
                    "database": {"build_seconds": solver.build_seconds, "load_seconds": solver.load_seconds,
                                 "bytes": solver.database_bytes, "patterns": solver.pattern_count,
                                 "from_cache": solver.from_cache}}
        # Saved unless the records there are another run's (the engine refuses to mix them; keep its tuning).
        if tuning_file is not None and not (tuning_file.parent / IdentifyTrials.name).exists():
            save_tuning(tuning_file, tuning_key, tuned)

    options = IdentifyTrialOptions(
        setups=",".join(setup_names), algorithms=",".join(algorithms), peers=",".join(peers),
        peer_settings=peer_settings_text({key: s["settings"] for key, s in tuned.items()}), scenes=scenes,
        hard_scenes=hard_scenes, seed=seed, identify_config=identify_config,
        peer_cache=str(cache) if cache is not None else "")
    blocks = options.blocks()
    trial_count = sum(b.count for b in blocks)
    tuning_calls = calls[0]

    def engine_progress(done: int, _total: int) -> None:
        if progress is not None:
            progress(tuning_calls + done, calls_total, "campaign engine")

    rows, run = [], {}
    if trial_count:
        table, run = run_trials(IdentifyTrials(), trial_count, dataclasses.asdict(options), engine,
                                seed=seed, log=log, progress=engine_progress)
        rows = records(table)
        failed = errors(table)
        for line in failed[:10]:
            log(f"trial raised: {line}")
        if failed:
            log(f"{len(failed)} of {trial_count} trials raised; counted inconclusive with status 'error'")
    for block in blocks:
        scene_list = scene_lists[block.setup]
        out = block_outcomes(block, rows[block.first_task:block.first_task + block.count], scene_list)
        summary = summarize(out, scene_list)
        entry = entries[block.setup]["solvers"]
        entry[block.solver] = {**tuned[(block.setup, block.solver)], **summary} if block.peer else \
            {"kind": "ours", **summary}
        log(f"{block.setup} {block.solver}"
            + (f" [{entry[block.solver]['settings']}]" if block.peer else "")
            + f": {summary['correct']}/{summary['inconclusive']}/{summary['incorrect']} "
              "(correct/inconclusive/incorrect)")
    results: dict = {"setups": entries}
    ours = [s for e in results["setups"].values() for s in e["solvers"].values() if s["kind"] == "ours"]
    theirs = [s for e in results["setups"].values() for s in e["solvers"].values() if s["kind"] == "peer"]
    results["totals"] = {
        "ours": {"incorrect": sum(s["incorrect"] for s in ours), "calls": sum(s["scenes"] for s in ours)},
        "peers": {"incorrect": sum(s["incorrect"] for s in theirs), "calls": sum(s["scenes"] for s in theirs)},
    }
    results["meta"] = {
        "command": None, "date": f"{dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC",
        "elapsed_s": time.perf_counter() - run_started, "seed": seed, "scenes": scenes, "hard_scenes": hard_scenes,
        "tune_scenes": tune_scenes, "max_time_s": config.max_time_s, "algorithms": list(algorithms),
        "peers": list(peers), "machine": machine_info(),
        "reference_algorithm": DEFAULT_ALGORITHM if DEFAULT_ALGORITHM in algorithms else algorithms[0],
        "engine": engine_line(run) if run else None, "engine_run": run or None,
        "failed_trials": sum(1 for row in rows if row["error"]),
    }
    return results


# ----------------------------------------------------------------------------- report


def _pct(value) -> str:
    return "–" if value is None or not np.isfinite(value) else f"{value:.1f}"


def _stats_text(stats: dict) -> str:
    return ", ".join(f"{k} {v:.2f}" for k, v in stats.items()) or "–"


def setup_table(name: str, entry: dict, reference: str | None) -> list[str]:
    split = name in SPLIT_SETUPS
    ref_ms = entry["solvers"].get(reference, {}).get("time_ms", {}) or {}
    header = ["solver", "correct %", "inconclusive %", "incorrect", "wrong id"]
    if split:
        header += ["≥4 stars: correct %", "≥4: inconcl. %", "≥4: incorrect"]
    header += ["stars used", "per-call stats (mean)", "median ms", "p99 ms", "max ms", f"median / {reference}"]
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
    for solver, s in entry["solvers"].items():
        label = solver if s["kind"] == "ours" else f"{solver} {s['version']} [{s['settings']}]"
        t = s["time_ms"] or {}
        ratio = t.get("median", float("nan")) / ref_ms["median"] if ref_ms.get("median") else float("nan")
        row = [label, _pct(s["correct_pct"]), _pct(s["inconclusive_pct"]), str(s["incorrect"]),
               str(s["wrong_ids"]) if s["kind"] == "peer" else "="]
        if split:
            g = s["ge4"]
            n4 = g["scenes"]
            row += [_pct(100 * g[CORRECT] / n4 if n4 else None), _pct(100 * g[INCONCLUSIVE] / n4 if n4 else None),
                    str(g[INCORRECT])]
        row += ["–" if s["stars_used_mean"] is None else f"{s['stars_used_mean']:.2f}", _stats_text(s["stats_mean"]),
                f"{t.get('median', float('nan')):.2f}", f"{t.get('p99', float('nan')):.1f}",
                f"{t.get('max', float('nan')):.1f}", f"{ratio:.2f}"]
        lines.append("| " + " | ".join(row) + " |")
    for label, text in PAPER_ROWS.get(name, []):
        lines.append(f"| {label} | {text} |" + " |" * (len(header) - 2))
    return lines


def overview_table(results: dict) -> list[str]:
    names = list(results["setups"])
    solvers = list(dict.fromkeys(solver for e in results["setups"].values() for solver in e["solvers"]))
    lines = ["| solver | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for solver in solvers:
        cells = []
        for name in names:
            s = results["setups"][name]["solvers"].get(solver)
            cells.append("–" if s is None else f"{_pct(s['correct_pct'])} ({s['incorrect']})")
        lines.append(f"| {solver} | " + " | ".join(cells) + " |")
    return lines


def peer_settings_lines(results: dict) -> list[str]:
    lines = ["| setup | peer | kept | database settings | solve settings | DB build s | DB MB | patterns | "
             "tuning: label → correct / inconcl. / incorrect (median ms) |", "|---|---|---|---|---|---:|---:|---:|---|"]
    for name, entry in results["setups"].items():
        for peer, s in entry["solvers"].items():
            if s["kind"] != "peer":
                continue
            db = s["database"]
            tuning = "; ".join(f"{t['label']} → {t.get('correct', '–')} / {t.get('inconclusive', '–')} / "
                               f"{t.get('incorrect', '–')} ({t['median_ms']:.2f})" if t.get("median_ms") is not None
                               else t["label"] for t in s["tuning"])
            settings = ", ".join(f"{k}={_short(v)}" for k, v in s["database_settings"].items())
            solve = ", ".join(f"{k}={_short(v)}" for k, v in s["solve_settings"].items())
            lines.append(f"| {name} | {peer} | {s['settings']} | {settings} | {solve} | {db['build_seconds']:.1f} | "
                         f"{db['bytes'] / 1e6:.1f} | {db['patterns']} | {tuning} |")
    return lines


# Why a goal row is not met where that follows from the method, not from this run (docs/IDENTIFICATION.md).
GOAL_NOTES = {
    "cole": "A third of the Cole scenes hold fewer than 4 true stars: a 3-star solution cannot reach the 1e-6 "
            "false-positive bound at 87 µrad (λ₃ ≈ 1e-2, docs/IDENTIFICATION.md).",
    "cole_false": "With one more spot the look-elsewhere factor C(n, m) grows, so more 4-star fields with a poor fit "
                  "miss the bound.",
    "toloei_4_136": "Cannot be met under a 1e-6 bound: C(140, 4) ≈ 1.6e7 four-spot subsets, each matching some "
                    "catalog 4-tuple by chance with probability ~1e-10 at 0.1 px, so four true stars among 136 false "
                    "ones are never distinguishable from chance.",
}


def goals_lines(results: dict) -> list[str]:
    """Return the goal rows of the default algorithm (meta.reference_algorithm), judged from this run, peers beside."""
    reference = results["meta"]["reference_algorithm"]
    setups = results["setups"]

    def solver(name: str, who: str = reference) -> dict | None:
        return setups.get(name, {}).get("solvers", {}).get(who)

    def peers_text(name: str, key: str = "correct_pct") -> str:
        parts = [f"{peer} {_pct(s[key])} %" + (f", {s['incorrect']} incorrect" if s["incorrect"] else "")
                 for peer in ("tetra3rs", "cedar-solve") if (s := solver(name, peer)) is not None]
        return f" (peers: {'; '.join(parts)})" if parts else ""

    def ge4_pct(s: dict) -> float | None:
        return 100.0 * s["ge4"][CORRECT] / s["ge4"]["scenes"] if s["ge4"]["scenes"] else None

    def met(ok: bool) -> str:
        return "met" if ok else "**not met**"

    rows = []
    if (s := solver("nominal")) is not None:
        rows.append(("nominal: 100 % correct", f"{_pct(s['correct_pct'])} % ({s['scenes']} scenes)",
                     met(s["correct"] == s["scenes"])))
        t, peer = s["time_ms"], solver("nominal", "tetra3rs")
        if t and peer and peer["time_ms"]:
            ratio = t["median"] / peer["time_ms"]["median"]
            rows.append(("nominal: median ≤ 2× tetra3rs, max ≤ 5 ms",
                         f"{t['median']:.2f} ms median = {ratio:.1f}× tetra3rs ({peer['time_ms']['median']:.2f} ms); "
                         f"p99 {t['p99']:.1f} ms, max {t['max']:.1f} ms", met(ratio <= 2.0 and t["max"] <= 5.0)))
    if (s := solver("cole")) is not None:
        rows.append(("Cole: ≥ 75 % of all scenes", f"{_pct(s['correct_pct'])} %{peers_text('cole')}",
                     met(s["correct_pct"] >= 75.0)))
        value = ge4_pct(s)
        rows.append(("Cole: ≥ 98 % of scenes with ≥ 4 true stars, 0 incorrect",
                     f"{_pct(value)} % of {s['ge4']['scenes']}, {s['incorrect']} incorrect",
                     met(value is not None and value >= 98.0 and s["incorrect"] == 0)))
    if (s := solver("cole_false")) is not None:
        value = ge4_pct(s)
        rows.append(("Cole + 1 false star: the same", f"{_pct(s['correct_pct'])} % of all, {_pct(value)} % of ≥ 4-star "
                     f"scenes, {s['incorrect']} incorrect{peers_text('cole_false')}",
                     met(s["correct_pct"] >= 75.0 and value is not None and value >= 98.0 and s["incorrect"] == 0)))
    for name, label, goal in (("toloei_6_50", "6 real + 50 false: ≥ 95 %", 95.0),
                              ("toloei_4_136", "4 real + 136 false: ≥ 50 %", 50.0)):
        if (s := solver(name)) is not None:
            rows.append((label, f"{_pct(s['correct_pct'])} % ({s['scenes']} scenes){peers_text(name)}",
                         met(s["correct_pct"] >= goal)))
    if (s := solver("fast")) is not None:
        rows.append(("FAST: ≥ 99.9 %, 0 incorrect", f"{_pct(s['correct_pct'])} %, {s['incorrect']} incorrect"
                     f"{peers_text('fast')}", met(s["correct_pct"] >= 99.9 and s["incorrect"] == 0)))
    totals = results["totals"]["ours"]
    rows.append(("≤ 1 incorrect in 10,000 scenes", f"{totals['incorrect']} in {totals['calls']:,} (all our "
                 "algorithms, all setups)", met(totals["incorrect"] <= max(1, totals["calls"] // 10_000))))
    lines = [f"### Goals (default algorithm `{reference}`)", "", "| goal | this run | met |", "|---|---|---|",
             *[f"| {goal} | {value} | {verdict} |" for goal, value, verdict in rows], ""]
    notes = [f"- {name}: {GOAL_NOTES[name]}" for name in GOAL_NOTES
             if (s := solver(name)) is not None and not s["correct"] == s["scenes"]]
    if notes:
        lines += ["Where a row falls short by the method itself:", "", *notes, ""]
    percentiles = all(s.get("time_ms_percentiles") for e in setups.values() for s in e["solvers"].values())
    lines += ["The same run as plots (`python -m bench.plots` from `bench_identify.json`). Success against the "
              "number of false stars per scene (red ring: an incorrect solution); on the 15° camera the Toloei setups "
              "add 50 and 136 false stars *and* keep only 6 and 4 real ones, so their drop is both effects:", "",
              "![identification success vs false stars](images/identify_false_stars.png)", "",
              "Solve time per call of every algorithm and peer ("
              + ("boxes p25-p75, whiskers p1-p99" if percentiles else "median, 99th percentile and maximum") + "):",
              "", "![solve-time distributions vs the peers](images/identify_times.png)", ""]
    return lines


def _short(value) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def machine_info() -> dict:
    versions = {"numpy": np.__version__}
    for package in ("tetra3rs", "cedar-solve"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "python": sys.version.replace("\n", " "),
            "platform": platform.platform(), "versions": versions}


def render_markdown(results: dict) -> str:
    meta = results["meta"]
    machine = meta["machine"]
    reference = meta["reference_algorithm"]
    totals = results["totals"]
    lines = [
        "## Identification",
        "",
        f"Command: `{meta['command']}`. Measured {meta['date']} in {meta['elapsed_s']:.0f} s. Machine: "
        f"{machine['cpu']}, `nproc` = {machine['cores']}; `python -VV`: Python {machine['python']}; numpy "
        f"{machine['versions']['numpy']}; tetra3rs {machine['versions']['tetra3rs'] or 'not installed'}, cedar-solve "
        f"{machine['versions']['cedar-solve'] or 'not installed'}.",
        *([f"{meta['engine'][:1].upper()}{meta['engine'][1:]} (a trial = one solver call on one scene)"
           + (f"; {meta['failed_trials']} trials raised (counted inconclusive, status error)."
              if meta.get("failed_trials") else ".")] if meta.get("engine") else []),
        "",
        f"- Scenes: `star_tracker.sim.scenes.SETUPS`, seed {meta['seed']}, the same centroid lists for every solver; "
        f"{meta['scenes']} per setup ({', '.join(HARD_SETUPS)}: at most the first {meta['hard_scenes']}, since most "
        "calls there run to the time limit).",
        f"- Ours: every registered algorithm, database per setup (below), default `IdentifyConfig` (time limit "
        f"{meta['max_time_s']:g} s per call; on {', '.join(HARD_SETUPS)} `max_pattern_spots` = 100, so every "
        "spot may form patterns as in Toloei's method). **correct** = solved and every returned HIP id is the truth "
        "behind its spot; **incorrect** = solved with any wrong id; **inconclusive** = no solution (no match, time "
        "limit, too few spots).",
        "- Peers: the same guide stars (Hipparcos at the scene epoch, Hp, the setup's magnitude limit) in their own "
        "pattern databases built for the camera's FOV; FOV given to 0.1 deg; the same time limit. correct = "
        "boresight within 1 arcmin and roll within 1 deg of the truth. `wrong id` counts solved results that name "
        "any spot with the wrong HIP id (for ours that is the incorrect count). Settings: the best of a few "
        f"candidates on a separate tuning set (another seed; {meta['tune_scenes']} scenes, at most "
        f"{HARD_TUNE_SCENES} on the hard setups) by most correct minus 10x incorrect, then fewest wrong ids, then "
        "the faster (table at the end). Both peers solve single-threaded (tetra3rs: compiled Rust; cedar-solve: "
        "numpy/Python). A peer's wrong ids with a correct attitude are mostly close doubles (e.g. the 5.6 mag "
        "companion 19\" from a 2.9 mag star, which the scenes merge into the brighter star's spot).",
        ("- Times: wall clock around the call (`time.perf_counter`) on the worker process that ran it, one call at a "
         f"time per worker ({meta.get('engine_run', {}).get('threads', '?')} worker(s) side by side, ours and the "
         "peers' alike; one by default, so a time is a quiet core's), after untimed warm-up "
         "calls per solver and setup in each worker process (on the first scene, until one ends within the time "
         "limit, at most 3); the peers' tuning ran in the main process. "
         if meta.get("engine") else
         "- Times: wall clock around the call (`time.perf_counter`), one process, one call at a time, after one "
         "untimed warm-up call per solver and setup. ")
        + "Per-call stats: the algorithms' own counters (e.g. pivots) averaged over "
        "the calls that report them. The machine is a shared 2-core VM: absolute times vary between runs; compare "
        "within one run.",
        "",
        f"**Incorrect over all scenes: {totals['ours']['incorrect']} in {totals['ours']['calls']}** (our algorithms, "
        f"all setups); peers: {totals['peers']['incorrect']} in {totals['peers']['calls']}.",
        "",
        "Overview, correct % (incorrect count):",
        "",
        *overview_table(results),
        "",
        *goals_lines(results),
    ]
    for name, entry in results["setups"].items():
        db = entry["database"]
        lines += [
            f"### {name}",
            "",
            f"{entry['description'][:1].upper()}{entry['description'][1:]}. {entry['scenes']} scenes, "
            f"{entry['true_stars_mean']:.2f} true stars and {entry['spots_mean']:.1f} spots on average, "
            f"{entry['scenes_ge4_true_stars']} scenes with >= 4 true stars. Our database: Hp <= "
            f"{db['magnitude_limit']:g}, pairs up to {db['max_pair_angle_deg']:.2f} deg, {db['stars']} stars, "
            f"{db['pairs']} pairs.",
            "",
            *setup_table(name, entry, reference),
            "",
        ]
        errors = [(solver, s) for solver, s in entry["solvers"].items() if s["errors"]]
        for solver, s in errors:
            lines += [f"{solver}: {s['errors']} calls raised ({s['first_error']}); counted inconclusive.", ""]
    if any(s["kind"] == "peer" for e in results["setups"].values() for s in e["solvers"].values()):
        lines += ["### Peer settings and database builds", "",
                  "Build times are those of the first build (databases are cached per settings under "
                  "`~/.cache/star_tracker/bench_peers`).", "", *peer_settings_lines(results), ""]
    return "\n".join(lines)


def _names(text: str | None, known, what: str) -> list[str]:
    if text is None:
        return list(known)
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in known]
    if unknown:
        raise SystemExit(f"unknown {what}: {', '.join(unknown)}; choose from {', '.join(known)}")
    return names


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.strip().split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=1000, help="scenes per setup (default 1000)")
    parser.add_argument("--hard-scenes", type=int, default=100,
                        help=f"at most this many scenes for {', '.join(HARD_SETUPS)} (default 100)")
    parser.add_argument("--tune-scenes", type=int, default=100,
                        help="peers' tuning scenes per setup, another seed (default 100; 0: first candidate)")
    parser.add_argument("--setups", help="comma-separated setups (default: all of SETUPS)")
    parser.add_argument("--algorithms", help="comma-separated algorithms (default: all of ALGORITHMS)")
    parser.add_argument("--no-peers", action="store_true", help="our algorithms only")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    parser.add_argument("--output", type=Path, help="write the '## Identification' section of this Markdown file")
    parser.add_argument("--json", type=Path, help="raw numbers (default: bench_identify.json beside --output)")
    parser.add_argument("--from-json", type=Path, metavar="JSON",
                        help="measure nothing: write the section of --output from these saved results")
    add_engine_arguments(parser, timed=True)
    args = parser.parse_args(argv)
    if args.from_json:
        text = render_markdown(json.loads(args.from_json.read_text()))
        print(text)
        if args.output:
            write_section(args.output, text)
        return
    setups = _names(args.setups, SETUPS, "setups")
    algorithms = _names(args.algorithms, ALGORITHMS, "algorithms")
    peers = [] if args.no_peers else peer_adapters.usable_peers()

    results = run_benchmark(setups, algorithms, args.scenes, args.seed, peers, args.tune_scenes, args.hard_scenes,
                            log=lambda text: print(text, file=sys.stderr, flush=True), progress=report_progress,
                            engine=args)
    # The command as typed: it holds the engine options (--workers, --scheduler, --campaign-output) given.
    results["meta"]["command"] = "python -m bench.bench_identify" + "".join(
        f" {shlex.quote(a)}" for a in (argv if argv is not None else sys.argv[1:]))
    text = render_markdown(results)
    print(text)
    json_path = args.json or (args.output.parent / "bench_identify.json" if args.output else None)
    if args.output:
        write_section(args.output, text)
    if json_path:
        json_path.write_text(json.dumps(results, indent=1, default=float) + "\n")


if __name__ == "__main__":
    main()
