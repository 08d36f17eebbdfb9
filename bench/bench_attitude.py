# SPDX-License-Identifier: Apache-2.0
"""
Attitude accuracy and covariance consistency of render -> extract_spots -> hybrid identify.

The in-process chain, at rest and under body rates.

    python -m bench.bench_attitude [--frames N] [--workers W] [--scheduler ADDR] [--campaign-output DIR]
                                   [--output docs/BENCHMARKS.md]

Default camera (1024 x 1024, 15 deg), SensorModel() defaults (0.1 s exposure), Hipparcos to
Hp 7.5 at the database epoch, default CentroidConfig (saturation_adu = 0: clipped stars must be
found by their flat tops), default database and IdentifyConfig, algorithm "hybrid". Attitudes
uniform over SO(3) (pointings all over the sky, any roll), a fixed seed. Under a rate,
extract_spots gets the true rate as its smear model (what the live centroider does once the
tracker publishes its rate).

The frames run on the campaign engine (bench/campaign_trials.py) as the kind `bench-attitude`
(AttitudeFrames): one trial = one frame of one case, the tasks numbered over CASES in order
(the rest case's --frames frames first, then each rate case's half of it). A frame's attitude,
body rate and noise seed are drawn as they always were (case_frames: per case, in frame order,
from SEED), so the figures do not depend on --workers (local worker processes, default every
core), on --scheduler tcp://HOST:8786 (a Dask cluster; $DASK_SCHEDULER_ADDRESS too) or on the
batching. --campaign-output DIR keeps the records (Parquet, DIR/bench-attitude) and resumes an
interrupted run. The per-stage times are measured on the worker that ran the frame, beside the
other frames in flight: contended figures, not latency (the section's engine line says where).
--jobs is a deprecated alias of --workers.

Errors: d = rotation vector of R_true^T R_est in the sensor frame (R_est = R_true exp([d]x),
the convention of the published covariance P). cross-boresight = |(d_x, d_y)|, roll = |d_z|.
NEES = d^T P^-1 d (3-DOF, expected mean 3); cross-boresight NEES uses the x/y block of P
(2-DOF, expected 2); roll NEES d_z^2 / P_zz (1-DOF, expected 1).

Diagnostics (truth used only here): each matched spot against the renderer's true pixel
position of its star: chi^2 = e^T C^-1 e with the centroider's covariance C (2-DOF, expected
mean 2), by SNR, Hp, distance to the nearest other rendered star and flag. The published NEES
by frame category (a matched spot flagged saturated / blended; a matched star with another
rendered star within NEIGHBOUR_PX; none of these). And the NEES of the same matches refitted
(as the identifier: QUEST with each ray's isotropic sigma, then the maximum-likelihood
refinement with its full 2-D covariance, attitude_estimation.refine_with_covariances) under
changes that isolate one cause each: "with the floor" = QUEST with every spot's sigma floored
at IdentifyConfig.centroid_sigma_floor_px (what the identifier published before);
"isotropic" = QUEST with the isotropic sigmas only (no 2-D refinement); "no rejection" = every
matched star kept (the identifier leaves out stars beyond 5 sigma); "- clipped" = without
spots that have a pixel at the sensor's full-well clip level (found in the image);
"- crowded" = without stars that have another rendered star within NEIGHBOUR_PX.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from star_tracker.campaign import CampaignKind
from star_tracker.models.attitude import ARCSEC, matrix_to_rotation_vector
from star_tracker.models.attitude_estimation import quest, refine_with_covariances
from star_tracker.models.camera import CameraModel
from star_tracker.models.catalog import load_hipparcos
from star_tracker.centroid import FLAG_BLENDED, FLAG_EDGE, FLAG_SATURATED, CentroidConfig, extract_spots
from star_tracker.centroid.streak.smear import SmearModel
from star_tracker.identify import DatabaseConfig, IdentifyConfig, load_or_build_database, make_identifier
from star_tracker.identify.base import direction_covariance
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import KIND_STAR, StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel
from .campaign_trials import add_engine_arguments, engine_arguments_text, engine_line, errors, log_stderr
from .campaign_trials import records as table_records
from .campaign_trials import run_trials
from .machine import cpu_model
from .report import write_section
from .scenes import random_rotation

SECTION = "## Attitude accuracy and covariance"
SEED = 2026
MAGNITUDE_LIMIT = 7.5
CHI2_3_997 = 13.93  # chi^2 with 3 DOF: P(X > 13.93) = 0.003
GOAL_CROSS_ARCSEC, GOAL_ROLL_ARCSEC, GOAL_NEES, GOAL_NEES_TOLERANCE = 2.0, 20.0, 3.0, 0.3
# A matched spot is its star's when the star lies within WRONG_ID_PX of it, or when the star is the
# rendered star nearest the spot and within WRONG_ID_CHI2 of the spot's own covariance (a faint
# 20 px streak's along-track sigma is ~1 px: its own star can be 3-4 px off); else a wrong id.
WRONG_ID_PX = 3.0
WRONG_ID_CHI2 = 25.0  # 5 sigma in 2-D
NEIGHBOUR_PX = 10.0  # "crowded": another rendered star within this distance [px]
# (name, kind, rate [deg/s]): "rest", "cross" (random direction in the x/y plane), "roll" (about +Z).
CASES = [("at rest", "rest", 0.0), ("cross 0.5 deg/s", "cross", 0.5), ("cross 1 deg/s", "cross", 1.0),
         ("cross 2 deg/s", "cross", 2.0), ("cross 3 deg/s", "cross", 3.0), ("roll 3 deg/s", "roll", 3.0)]
SNR_BINS = [5, 20, 50, 100, 300, 1e9]
HP_BINS = [-2, 3, 4, 5, 6, 7, 7.5]
NEIGHBOUR_BINS = [0, 5, 10, 20, 1e9]
COUNT_BINS = [4, 10, 20, 30, 40, 60, 1000]
# NEES variants of the same matches (module docstring): key -> label.
VARIANTS = {"nees_floored": "with the floor", "nees_isotropic": "isotropic", "nees_all_kept": "no rejection",
            "nees_unclipped": "- clipped", "nees_isolated": "- crowded"}
# Frame categories of the published NEES: key -> label (a frame may be in several).
CATEGORIES = {"saturated": "a saturated spot", "blended": "a blended spot", "crowded": "a crowded star",
              "clean": "none of these"}


def body_rate(kind: str, rate_deg_s: float, rng: np.random.Generator) -> np.ndarray:
    """Sensor-frame body rate [rad/s] of a case."""
    rate = np.radians(rate_deg_s)
    if kind == "cross":
        azimuth = rng.uniform(0.0, 2.0 * np.pi)
        return rate * np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    if kind == "roll":
        return np.array([0.0, 0.0, rate])
    return np.zeros(3)


def nees_parts(d: np.ndarray, cov: np.ndarray) -> tuple[float, float, float]:
    """(3-DOF, cross-boresight 2-DOF from the x/y block, roll 1-DOF) NEES of error d [rad]."""
    return (float(d @ np.linalg.solve(cov, d)), float(d[:2] @ np.linalg.solve(cov[:2, :2], d[:2])),
            float(d[2] ** 2 / cov[2, 2]))


class Chain:
    """The renderer, centroider and identifier of the default pipeline, and per-stage timers."""

    def __init__(self):
        self.camera = CameraModel.from_fov(1024, 1024, np.radians(15.0))
        self.sensor = SensorModel()
        self.database = load_or_build_database(DatabaseConfig())
        catalog = load_hipparcos().at_epoch(self.database.config.epoch_jyear)
        self.renderer = StarFieldRenderer(self.camera, self.sensor, catalog, magnitude_limit=MAGNITUDE_LIMIT)
        self.centroid_config = CentroidConfig()
        self.identify_config = IdentifyConfig()
        self.identifier = make_identifier("hybrid", self.database, self.identify_config)
        self.identifier.warm_up(self.camera)
        self.hp_of_hip = dict(zip(self.database.hip.tolist(), self.database.magnitude.tolist()))

    def run_frame(self, rotation: np.ndarray, omega: np.ndarray, seed: int) -> dict:
        camera = self.camera
        t0 = time.perf_counter()
        frame = self.renderer.render(ConstantRateMotion(rotation, omega), 0.0, seed)
        t1 = time.perf_counter()
        spots = extract_spots(frame.image, self.centroid_config, SmearModel(camera, omega, self.sensor.exposure_s))
        t2 = time.perf_counter()
        result = self.identifier.identify(spots, camera)
        t3 = time.perf_counter()
        record = {"render_ms": 1e3 * (t1 - t0), "centroid_ms": 1e3 * (t2 - t1), "identify_ms": 1e3 * (t3 - t2),
                  "spots": len(spots), "solved": result.solved}
        if not result.solved:
            return record
        truth = frame.truth
        error = matrix_to_rotation_vector(truth.rotation.T @ result.attitude.rotation)
        cov_att = result.attitude.covariance
        record.update(error=error, nees=nees_parts(error, cov_att), stars=int(result.hip.size),
                      predicted_var=(float(cov_att[0, 0] + cov_att[1, 1]), float(cov_att[2, 2])))

        # Each matched spot against its star's true mid-exposure pixel position.
        star = truth.kind == KIND_STAR
        sx, sy, shp = truth.x[star], truth.y[star], truth.hip[star]
        where = {int(h): i for i, h in enumerate(shp)}
        index = np.array([where.get(int(h), -1) for h in result.hip])
        si = result.spot_index
        tx, ty = np.where(index >= 0, sx[index], np.nan), np.where(index >= 0, sy[index], np.nan)
        ex, ey = spots.x[si] - tx, spots.y[si] - ty
        cov = spots.cov[si]
        e = np.stack([ex, ey], axis=1)
        chi2 = np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov), e)
        gap = np.hypot(tx[:, None] - sx[None], ty[:, None] - sy[None])
        gap[gap < 1e-6] = np.inf  # the star itself
        sigma_px = np.sqrt(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]))
        clipped = self.clipped(frame.image, spots.x[si], spots.y[si], spots.streak_length[si])
        neighbour = gap.min(axis=1)
        flags = spots.flags[si]
        nearest = shp[np.argmin(np.hypot(spots.x[si][:, None] - sx[None], spots.y[si][:, None] - sy[None]), axis=1)]
        own_star = (np.hypot(ex, ey) <= WRONG_ID_PX) | ((nearest == result.hip) & (chi2 <= WRONG_ID_CHI2))
        record.update(wrong_ids=int(np.sum(~own_star)),
                      star_chi2=chi2, star_snr=spots.snr[si], star_flags=flags, star_clipped=clipped,
                      star_hp=np.array([self.hp_of_hip.get(int(h), np.nan) for h in result.hip]),
                      star_neighbour_px=neighbour, star_sigma_px=sigma_px, clipped_frame=bool(clipped.any()))
        crowded = neighbour <= NEIGHBOUR_PX
        category = {"saturated": bool(np.any(flags & FLAG_SATURATED)), "blended": bool(np.any(flags & FLAG_BLENDED)),
                    "crowded": bool(crowded.any())}
        category["clean"] = not any(category.values())
        record["category"] = category

        # The same matches refitted under one change each (module docstring).
        body, stars = result.body_vectors, result.star_vectors
        ray_cov = direction_covariance(camera, spots.x[si], spots.y[si], cov)
        sigma = np.sqrt(0.5 * np.trace(ray_cov, axis1=1, axis2=2))
        floor = self.identify_config.centroid_sigma_floor_px * camera.pixel_scale_rad
        floored = quest(body, stars, np.maximum(sigma, floor))
        d = matrix_to_rotation_vector(truth.rotation.T @ floored.rotation)
        record["nees_floored"] = nees_parts(d, floored.covariance)
        everyone = np.ones(si.size, bool)
        for name, keep in (("unclipped", ~clipped), ("isolated", ~crowded), ("all_kept", everyone)):
            if keep.sum() < 4:
                continue
            start = quest(body[keep], stars[keep], sigma[keep])
            solution, _, _ = refine_with_covariances(start.rotation, body[keep], stars[keep], ray_cov[keep])
            d = matrix_to_rotation_vector(truth.rotation.T @ solution.rotation)
            record[f"nees_{name}"] = nees_parts(d, solution.covariance)
        record["nees_isotropic"] = nees_parts(matrix_to_rotation_vector(truth.rotation.T @ start.rotation),
                                              start.covariance)
        return record

    def clipped(self, image: np.ndarray, x: np.ndarray, y: np.ndarray, streak_length: np.ndarray) -> np.ndarray:
        """
        Return the spots with a pixel at the sensor's full-well clip level near their centre.

        The clip level is full_well / gain + bias, rounded; near: within 3 px plus half the streak.
        """
        level = np.floor(self.sensor.full_well_e / self.sensor.gain_e_per_adu + self.sensor.bias_adu + 0.5)
        height, width = image.shape
        out = np.zeros(x.size, bool)
        for k, (cx, cy, length) in enumerate(zip(x, y, streak_length)):
            half = 3 + int(np.ceil(0.5 * length))
            c, r = int(round(cx)), int(round(cy))
            window = image[max(r - half, 0):min(r + half + 1, height), max(c - half, 0):min(c + half + 1, width)]
            out[k] = window.size > 0 and window.max() >= level
        return out


def case_frames(case_index: int, kind: str, rate_deg_s: float, frames: int) -> list[tuple]:
    """(rotation, body rate, seed) of each frame of a case, drawn in frame order."""
    rng = np.random.default_rng([SEED, case_index])
    out = []
    for k in range(frames):
        rotation = random_rotation(rng)
        out.append((rotation, body_rate(kind, rate_deg_s, rng), frame_seed(SEED, case_index * 1_000_000 + k)))
    return out


def case_frame_counts(frames: int) -> list[int]:
    """Frames of each case in CASES: `frames` at rest, half of it (at least 1) under each rate."""
    return [frames if kind == "rest" else max(frames // 2, 1) for _, kind, _ in CASES]


@dataclass(frozen=True)
class AttitudeOptions:
    """The size of a run: frames at rest; each rate case gets half of it (at least 1)."""

    frames: int = 1000

    def __post_init__(self) -> None:
        if isinstance(self.frames, bool) or not isinstance(self.frames, int) or self.frames < 1:
            raise ValueError(f"bench-attitude options: frames={self.frames!r} must be a whole number >= 1")

    @property
    def trials(self) -> int:
        return sum(case_frame_counts(self.frames))

    def locate(self, task: int) -> tuple[int, int]:
        """Return (case index in CASES, frame within the case) of trial `task` (tasks numbered over CASES in order)."""
        for case, count in enumerate(case_frame_counts(self.frames)):
            if task < count:
                return case, task
            task -= count
        raise IndexError(f"task beyond the {self.trials} frames of --frames {self.frames}")


@dataclass
class _Shared:
    chain: Chain
    frames: list[list[tuple]]  # per case: (rotation, body rate [rad/s], noise seed) of each frame


# The record's columns. Chain.run_frame's dict is flattened into them (frame_columns) and rebuilt
# from them (frame_record): its 3-vector error and its tuples become one column each component,
# its category dict one bool column each, its per-star arrays list columns. A column is null where
# the dict has no key (an unsolved frame; a refit left out with fewer than 4 stars).
NEES_PARTS = ("", "_cross", "_roll")  # nees_parts' (3-DOF, x/y 2-DOF, roll 1-DOF)
STAR_COLUMNS = {"star_chi2": pa.float64(), "star_snr": pa.float64(), "star_flags": pa.int64(),
                "star_clipped": pa.bool_(), "star_hp": pa.float64(), "star_neighbour_px": pa.float64(),
                "star_sigma_px": pa.float64()}
STAR_DTYPES = {"star_flags": np.uint32, "star_clipped": bool}  # as extract_spots gives them (others float64)
ERROR_COLUMNS = ("error_x_rad", "error_y_rad", "error_z_rad")  # "error" is the engine's column (a trial that raised)
PREDICTED_COLUMNS = ("predicted_cross_var_rad2", "predicted_roll_var_rad2")


class AttitudeFrames(CampaignKind):
    """
    One frame of one case through render -> extract_spots -> hybrid identify, scored against the truth.

    Trial `task` is frame k of case c (AttitudeOptions.locate); its attitude, body rate and noise
    seed are case_frames' (drawn per case from SEED, in frame order, precomputed in `prepare`):
    the engine's rng is not used, so the frames are the ones this benchmark always ran.
    """

    name = "bench-attitude"
    description = "bench_attitude: a rendered frame at rest or under a body rate, its error and NEES diagnostics"
    options_type = AttitudeOptions
    default_trials = 0  # the options': --frames at rest, half of it per rate case
    default_batch = 20  # frames of 20-80 ms: 0.4-1.6 s a Dask task
    columns = (pa.field("case", pa.int32()), pa.field("frame", pa.int32()),
               pa.field("render_ms", pa.float64()), pa.field("centroid_ms", pa.float64()),
               pa.field("identify_ms", pa.float64()), pa.field("spots", pa.int32()), pa.field("solved", pa.bool_()),
               pa.field("stars", pa.int32()), pa.field("wrong_ids", pa.int32()), pa.field("clipped_frame", pa.bool_()),
               *(pa.field(name, pa.float64()) for name in ERROR_COLUMNS),
               *(pa.field(name, pa.float64()) for name in PREDICTED_COLUMNS),
               *(pa.field(key + part, pa.float64()) for key in ("nees", *VARIANTS) for part in NEES_PARTS),
               *(pa.field(f"category_{key}", pa.bool_()) for key in CATEGORIES),
               *(pa.field(name, pa.list_(kind)) for name, kind in STAR_COLUMNS.items()))

    def prepare(self, options: AttitudeOptions) -> _Shared:
        frames = [case_frames(index, kind, rate, count)
                  for index, ((_, kind, rate), count) in enumerate(zip(CASES, case_frame_counts(options.frames)))]
        return _Shared(Chain(), frames)

    def trial(self, shared: _Shared, options: AttitudeOptions, task: int, rng: np.random.Generator) -> dict:
        case, frame = options.locate(task)
        rotation, omega, seed = shared.frames[case][frame]
        return {"case": case, "frame": frame, **frame_columns(shared.chain.run_frame(rotation, omega, seed))}

    def summarize(self, table: pa.Table, options: AttitudeOptions) -> dict:
        return {}  # the benchmark's summarize() makes the figures from frame_record()s


def frame_columns(record: dict) -> dict:
    """Return Chain.run_frame's record as the kind's columns (nulls where it has no key)."""
    out = {name: None for name in (f.name for f in AttitudeFrames.columns)}
    out.update({key: record[key] for key in ("render_ms", "centroid_ms", "identify_ms", "spots", "solved")})
    if not record["solved"]:
        return out
    out.update(stars=record["stars"], wrong_ids=record["wrong_ids"], clipped_frame=record["clipped_frame"])
    out.update(zip(ERROR_COLUMNS, map(float, record["error"])))
    out.update(zip(PREDICTED_COLUMNS, record["predicted_var"]))
    for key in ("nees", *VARIANTS):
        if key in record:
            out.update({key + part: value for part, value in zip(NEES_PARTS, record[key])})
    out.update({f"category_{key}": value for key, value in record["category"].items()})
    out.update({name: record[name].tolist() for name in STAR_COLUMNS})
    return out


def frame_record(row: dict) -> dict:
    """Return the dict Chain.run_frame made (what summarize reads) from a row of the kind's table (records())."""
    out = {key: row[key] for key in ("render_ms", "centroid_ms", "identify_ms", "spots", "solved")}
    if not row["solved"]:
        return out
    out.update(error=np.array([row[name] for name in ERROR_COLUMNS]), stars=row["stars"],
               wrong_ids=row["wrong_ids"], clipped_frame=row["clipped_frame"],
               predicted_var=tuple(row[name] for name in PREDICTED_COLUMNS),
               category={key: row[f"category_{key}"] for key in CATEGORIES})
    for key in ("nees", *VARIANTS):
        if row[key] is not None:
            out[key] = tuple(row[key + part] for part in NEES_PARTS)
    for name in STAR_COLUMNS:
        out[name] = np.asarray(row[name], dtype=STAR_DTYPES.get(name, np.float64))
    return out


def run_cases(frames: int, args: argparse.Namespace | None = None) -> tuple[list[list[dict]], list[str], dict]:
    """
    Run every frame of every case on the campaign engine.

    Return case_records() of the frames' table and what the engine did (its run dict). args:
    the engine arguments (None = a local cluster on every core, records in a temporary directory).
    """
    kind = AttitudeFrames()  # run_trials takes it from bench.bench_attitude when this module is __main__
    options = AttitudeOptions(frames)
    table, run = run_trials(kind, options.trials, {"frames": frames}, args, seed=SEED, log=log_stderr)
    return (*case_records(table, frames), run)


def case_records(table: pa.Table, frames: int) -> tuple[list[list[dict]], list[str]]:
    """
    Return each case's frame records from the kind's table (task order) of a --frames run.

    The records are Chain.run_frame's dicts in frame order, frames that raised left out; beside
    them the errors of those ("case c frame k, task t: ...").
    """
    options = AttitudeOptions(frames)
    per_case: list[list[dict]] = [[] for _ in CASES]
    failed = []
    raised = iter(errors(table))  # "task t: error" of the rows that raised, in the table's order
    for row in table_records(table):
        case, frame = options.locate(row["task"])
        if row["error"]:
            failed.append(f"case {case} frame {frame}, {next(raised)}")
            continue
        per_case[case].append(frame_record(row))
    return per_case, failed


def binned_mean(values: np.ndarray, keys: np.ndarray, edges: list[float]) -> list[dict]:
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (keys >= lo) & (keys < hi)
        if m.any():
            rows.append({"lo": lo, "hi": hi, "n": int(m.sum()), "mean": float(np.mean(values[m])),
                         "median": float(np.median(values[m]))})
    return rows


def summarize(records: list[dict], floor_px: float) -> dict:
    solved = [r for r in records if r["solved"]]
    out = {"frames": len(records), "identified_pct": 100.0 * len(solved) / max(len(records), 1),
           "timing_ms": {stage: float(np.median([r[f"{stage}_ms"] for r in records]))
                         for stage in ("render", "centroid", "identify")}}
    if not solved:
        return out
    err = np.array([r["error"] for r in solved]) / ARCSEC
    cross, roll = np.hypot(err[:, 0], err[:, 1]), np.abs(err[:, 2])
    nees = np.array([r["nees"] for r in solved])
    stars = np.array([r["stars"] for r in solved])
    out.update(
        wrong_id_frames=int(sum(r["wrong_ids"] > 0 for r in solved)), stars_median=float(np.median(stars)),
        cross_rms_arcsec=float(np.sqrt(np.mean(cross**2))),
        cross_per_axis_rms_arcsec=float(np.sqrt(np.mean(cross**2) / 2)),
        cross_median_arcsec=float(np.median(cross)), cross_p95_arcsec=float(np.percentile(cross, 95)),
        roll_rms_arcsec=float(np.sqrt(np.mean(roll**2))), roll_median_arcsec=float(np.median(roll)),
        roll_p95_arcsec=float(np.percentile(roll, 95)),
        nees_mean=float(nees[:, 0].mean()), nees_cross_mean=float(nees[:, 1].mean()),
        nees_roll_mean=float(nees[:, 2].mean()), nees_tail_pct=float(100.0 * np.mean(nees[:, 0] > CHI2_3_997)),
        nees_mean_stderr=float(nees[:, 0].std() / np.sqrt(len(solved))),
    )
    # What the published covariance predicts for the same RMS values (mean variance over frames).
    predicted = np.array([r["predicted_var"] for r in solved])
    out["predicted_cross_rms_arcsec"] = float(np.sqrt(predicted[:, 0].mean()) / ARCSEC)
    out["predicted_roll_rms_arcsec"] = float(np.sqrt(predicted[:, 1].mean()) / ARCSEC)
    for name in VARIANTS:
        values = np.array([r[name] for r in solved if name in r])
        if values.size == 0:
            continue
        out[f"{name}_mean"] = float(values[:, 0].mean())
        out[f"{name}_cross_mean"] = float(values[:, 1].mean())
        out[f"{name}_roll_mean"] = float(values[:, 2].mean())
        out[f"{name}_tail_pct"] = float(100.0 * np.mean(values[:, 0] > CHI2_3_997))
    out["clipped_frames_pct"] = float(100.0 * np.mean([r["clipped_frame"] for r in solved]))
    chi2 = np.concatenate([r["star_chi2"] for r in solved])
    clipped = np.concatenate([r["star_clipped"] for r in solved])
    snr = np.concatenate([r["star_snr"] for r in solved])
    hp = np.concatenate([r["star_hp"] for r in solved])
    gap = np.concatenate([r["star_neighbour_px"] for r in solved])
    flags = np.concatenate([r["star_flags"] for r in solved])
    sigma_px = np.concatenate([r["star_sigma_px"] for r in solved])
    ok = np.isfinite(chi2)
    out["stars"] = {
        "matched": int(chi2.size), "chi2_mean": float(chi2[ok].mean()), "chi2_median": float(np.median(chi2[ok])),
        "below_floor_pct": float(100.0 * np.mean(sigma_px < floor_px)),
        "sigma_px_median": float(np.median(sigma_px)),
        "chi2_mean_isolated": float(chi2[ok & (gap > NEIGHBOUR_PX) & ~clipped].mean()),
        "clipped_pct": float(100.0 * np.mean(clipped)),
        "clipped_sigma_px_median": float(np.median(sigma_px[clipped])) if clipped.any() else float("nan"),
        "crowded_pct": float(100.0 * np.mean(gap <= NEIGHBOUR_PX)),
        "chi2_by_snr": binned_mean(chi2[ok], snr[ok], SNR_BINS),
        "chi2_by_hp": binned_mean(chi2[ok], hp[ok], HP_BINS),
        "chi2_by_neighbour_px": binned_mean(chi2[ok], gap[ok], NEIGHBOUR_BINS),
        "chi2_by_flag": {name: binned_mean(chi2[ok & sel], np.zeros(int((ok & sel).sum())), [0, 1])
                         for name, sel in (("edge", (flags & FLAG_EDGE) != 0), ("blended", (flags & FLAG_BLENDED) != 0),
                                           ("saturated", (flags & FLAG_SATURATED) != 0),
                                           ("clipped at full well", clipped),
                                           ("clipped, not flagged", clipped & ((flags & FLAG_SATURATED) == 0)))},
    }
    out["stars"]["clipped_flagged_pct"] = (float(100.0 * np.mean((flags[clipped] & FLAG_SATURATED) != 0))
                                           if clipped.any() else float("nan"))
    out["stars"]["saturated_flagged"] = int(np.sum((flags & FLAG_SATURATED) != 0))
    out["nees_by_category"] = {}
    for key in CATEGORIES:
        member = np.array([r["category"][key] for r in solved])
        if member.any():
            out["nees_by_category"][key] = {"frames": int(member.sum()), "mean": float(nees[member, 0].mean()),
                                            "tail_pct": float(100.0 * np.mean(nees[member, 0] > CHI2_3_997))}
    out["nees_by_star_count"] = binned_mean(nees[:, 0], stars, COUNT_BINS)
    for key in ("nees_floored", "nees_unclipped"):
        have = [r for r in solved if key in r]
        out[f"{key}_by_star_count"] = binned_mean(np.array([r[key][0] for r in have]),
                                                  np.array([r["stars"] for r in have]), COUNT_BINS)
    return out


def machine_info() -> dict:
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "python": sys.version.split()[0], "numpy": np.__version__,
            "platform": platform.platform()}


def figures(results: dict, image_dir: Path) -> list[Path]:
    """Error and NEES vs rate; the NEES diagnostics. Returns the written paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = [c for c in results["cases"] if "cross_rms_arcsec" in c]
    cross = [c for c in cases if c["kind"] in ("rest", "cross")]
    rolls = [c for c in cases if c["kind"] == "roll"]
    rate = [c["rate_deg_s"] for c in cross]
    fig, (ax_err, ax_nees) = plt.subplots(1, 2, figsize=(12, 4.5))
    for key, label, color, marker in (("cross", "cross-boresight", "C0", "o"), ("roll", "roll", "C1", "s")):
        ax_err.plot(rate, [c[f"{key}_rms_arcsec"] for c in cross], marker + "-", color=color, label=f"{label} RMS")
        ax_err.plot(rate, [c[f"predicted_{key}_rms_arcsec"] for c in cross], marker + ":", color=color, alpha=0.6,
                    label=f"{label}, published covariance")
        for c in rolls:
            ax_err.plot(c["rate_deg_s"], c[f"{key}_rms_arcsec"], "D", color=color, mfc="none", ms=9,
                        label=f"{label}, {c['name']}")
    ax_err.axhline(GOAL_CROSS_ARCSEC, color="C0", lw=0.8, ls="--")
    ax_err.axhline(GOAL_ROLL_ARCSEC, color="C1", lw=0.8, ls="--")
    ax_err.set_yscale("log")
    ax_err.set_xlabel("body rate [deg/s] (cross-boresight; open diamonds: roll rate)")
    ax_err.set_ylabel("attitude error 1-sigma (RMS) [arcsec]")
    ax_err.set_title("Attitude error vs rate (dashed: goals at rest)")
    ax_err.legend(fontsize=7)
    for (key, label), marker in zip({"nees": "published", **VARIANTS}.items(), "o^v<>"):
        line, = ax_nees.plot(rate, [c[f"{key}_mean"] / 3 for c in cross], marker + "-", label=label)
        for c in rolls:
            ax_nees.plot(c["rate_deg_s"], c[f"{key}_mean"] / 3, marker, mfc="none", ms=9, color=line.get_color())
    ax_nees.axhspan(1 - GOAL_NEES_TOLERANCE / 3, 1 + GOAL_NEES_TOLERANCE / 3, color="0.85", label="goal 3 +- 0.3")
    ax_nees.set_yscale("log")
    ax_nees.set_xlabel("body rate [deg/s] (open: roll rate)")
    ax_nees.set_ylabel("mean NEES / 3 (1 = consistent)")
    ax_nees.set_title("Covariance consistency: published and diagnostic variants")
    ax_nees.legend(fontsize=7)
    fig.tight_layout()
    image_dir.mkdir(parents=True, exist_ok=True)
    first = image_dir / "attitude_error_vs_rate.png"
    fig.savefig(first, dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for panel, key, title in ((0, "chi2_by_snr", "spot SNR"),
                              (1, "chi2_by_neighbour_px", "nearest other rendered star [px]")):
        edges = SNR_BINS if key == "chi2_by_snr" else NEIGHBOUR_BINS
        labels = [f"{lo:g}-{hi:g}".replace("-1e+09", "+") for lo, hi in zip(edges[:-1], edges[1:])]
        for c in cases:
            by = {r["lo"]: r["mean"] / 2 for r in c["stars"][key]}
            axes[panel].plot(range(len(labels)), [by.get(lo, np.nan) for lo in edges[:-1]], "o-", label=c["name"])
        axes[panel].set_xticks(range(len(labels)), labels)
        axes[panel].set_xlabel(title)
        axes[panel].set_yscale("log")
    axes[0].set_ylabel("mean spot chi2 / 2 (centroid vs truth)")
    axes[0].set_title("Centroid covariance vs SNR")
    axes[1].set_title("Centroid covariance vs crowding")
    rest = next(c for c in cases if c["kind"] == "rest")
    labels = [f"{r['lo']:g}-{r['hi']:g}".replace("-1000", "+") for r in rest["nees_by_star_count"]]
    for key, label in (("nees", "published"), ("nees_floored", "with the floor"), ("nees_unclipped", "- clipped")):
        by = {r["lo"]: r["mean"] / 3 for r in rest[f"{key}_by_star_count"]}
        axes[2].plot(range(len(labels)), [by.get(r["lo"], np.nan) for r in rest["nees_by_star_count"]], "o-",
                     label=label)
    axes[2].set_xticks(range(len(labels)), labels)
    axes[2].set_xlabel("matched stars per frame")
    axes[2].set_ylabel("mean NEES / 3")
    axes[2].set_yscale("log")
    axes[2].set_title("At rest: NEES vs star count")
    for ax in axes:
        ax.axhline(1.0, color="k", lw=0.8)
        ax.legend(fontsize=7)
    fig.tight_layout()
    second = image_dir / "attitude_nees_diagnostics.png"
    fig.savefig(second, dpi=110)
    plt.close(fig)
    return [first, second]


def verdict(ok: bool) -> str:
    return "**met**" if ok else "**not met**"


def bin_table(cases: list[dict], title: str, key: str) -> list[str]:
    edges = sorted({(r["lo"], r["hi"]) for c in cases for r in c["stars"][key]})
    lines = [f"| {title} | " + " | ".join(f"{lo:g}..{hi:g}".replace("..1e+09", "+") for lo, hi in edges) + " |",
             "|---|" + "---:|" * len(edges)]
    for c in cases:
        by = {(r["lo"], r["hi"]): r for r in c["stars"][key]}
        lines.append(f"| {c['name']} | " + " | ".join(f"{by[e]['mean']:.2f} ({by[e]['n']})" if e in by else "-"
                                                      for e in edges) + " |")
    return lines + [""]


def render_markdown(results: dict, images: list[Path], output: Path) -> str:
    meta, cases = results["meta"], results["cases"]
    m = meta["machine"]
    solved = [c for c in cases if "cross_rms_arcsec" in c]
    rest = next(c for c in cases if c["kind"] == "rest")
    where = meta.get("engine") or f"{meta['jobs']} worker processes"  # "jobs": a run before the campaign engine
    failed = meta.get("failed_trials", [])
    lines = [
        SECTION, "",
        f"Command: `{meta['command']}`. Measured {meta['date']} in {meta['elapsed_s']:.0f} s ({where}). "
        f"Machine: {m['cpu']}, `nproc` = {m['cores']}; Python {m['python']}, numpy {m['numpy']}.", "",
        *([f"**{len(failed)} frame(s) raised** and are left out of the figures: " + "; ".join(failed[:5])
           + (" ..." if len(failed) > 5 else ""), ""] if failed else []),
        "- Chain, in process: `StarFieldRenderer` (default camera 1024 x 1024 px, 15 deg; `SensorModel()` defaults, "
        f"exposure {meta['exposure_s']} s, full well clipped at {meta['clip_level_adu']:.0f} ADU; Hipparcos to Hp "
        f"{MAGNITUDE_LIMIT} at epoch {meta['epoch']}; no aberration, no false objects) -> `extract_spots` (default "
        "`CentroidConfig`, i.e. `saturation_adu` = 0, the uint16 maximum: clipped stars must be found by their flat "
        "tops or their fits; smear model with the TRUE body rate, as the live centroider once the tracker publishes "
        "its rate) -> `hybrid` identifier (default database and `IdentifyConfig`). Attitudes uniform over SO(3) "
        f"(seed {SEED}); cross-boresight rates in a random direction in the x/y plane; the roll case turns about the "
        "boresight.",
        "- Error d: rotation vector of R_true^T R_est (sensor frame). cross-boresight = |(d_x, d_y)| (a 2-D norm; "
        "per axis it is 1/sqrt(2) of that), roll = |d_z|; RMS = 1-sigma. NEES = d^T P^-1 d with the published "
        "covariance P (expected mean 3; +- its standard error over the frames); x/y: the 2-DOF block (expected 2); "
        f"roll: d_z^2 / P_zz (expected 1); tail: share of frames with NEES > chi2_3(0.997) = {CHI2_3_997} "
        f"(expected 0.3 %). wrong-id frames: a matched spot more than {WRONG_ID_PX:g} px from its star's true "
        f"position, unless that star is the rendered star nearest the spot and within chi2 {WRONG_ID_CHI2:g} of the "
        "spot's own covariance (a faint long streak's along-track error).", "",
        "| case | frames | identified | wrong-id frames | stars (median) | cross-boresight RMS [\"] | median / p95 "
        "[\"] | roll RMS [\"] | median / p95 [\"] | NEES (3) | NEES x/y (2) | NEES roll (1) | NEES tail (0.3 %) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for c in cases:
        if "cross_rms_arcsec" not in c:
            lines.append(f"| {c['name']} | {c['frames']} | {c['identified_pct']:.1f} % |" + " - |" * 10)
            continue
        lines.append(
            f"| {c['name']} | {c['frames']} | {c['identified_pct']:.1f} % | {c['wrong_id_frames']} | "
            f"{c['stars_median']:.0f} | {c['cross_rms_arcsec']:.2f} | {c['cross_median_arcsec']:.2f} / "
            f"{c['cross_p95_arcsec']:.2f} | {c['roll_rms_arcsec']:.1f} | {c['roll_median_arcsec']:.1f} / "
            f"{c['roll_p95_arcsec']:.1f} | {c['nees_mean']:.2f} +- {c['nees_mean_stderr']:.2f} | "
            f"{c['nees_cross_mean']:.2f} | {c['nees_roll_mean']:.2f} | {c['nees_tail_pct']:.1f} % |")
    pooled = results["pooled_moving"]
    lines.append(f"| all rate cases | {pooled['frames']} | | | | | | | | {pooled['nees_mean']:.2f} +- "
                 f"{pooled['nees_mean_stderr']:.2f} | {pooled['nees_cross_mean']:.2f} | "
                 f"{pooled['nees_roll_mean']:.2f} | {pooled['nees_tail_pct']:.1f} % |")
    nees_ok = [c for c in solved if abs(c["nees_mean"] - GOAL_NEES) <= GOAL_NEES_TOLERANCE]
    rest_ok = abs(rest["nees_mean"] - GOAL_NEES) <= GOAL_NEES_TOLERANCE
    lines += [
        "", "Goals:", "",
        f"- At rest, cross-boresight <= {GOAL_CROSS_ARCSEC:g}\" (1-sigma): {rest['cross_rms_arcsec']:.2f}\" (2-D RMS; "
        f"{rest['cross_per_axis_rms_arcsec']:.2f}\" per axis) "
        f"{verdict(rest['cross_rms_arcsec'] <= GOAL_CROSS_ARCSEC)}.",
        f"- At rest, roll <= {GOAL_ROLL_ARCSEC:g}\" (1-sigma): {rest['roll_rms_arcsec']:.1f}\" "
        f"{verdict(rest['roll_rms_arcsec'] <= GOAL_ROLL_ARCSEC)}.",
        f"- Mean NEES {GOAL_NEES:g} +- {GOAL_NEES_TOLERANCE:g} over >= 1000 frames: "
        f"{verdict(rest_ok and rest['frames'] >= 1000)} "
        f"at rest ({rest['nees_mean']:.2f} +- {rest['nees_mean_stderr']:.2f} over {rest['frames']} frames; x/y "
        f"{rest['nees_cross_mean']:.2f}, roll {rest['nees_roll_mean']:.2f}); {len(nees_ok)} of {len(solved)} cases "
        f"within the band; all {pooled['frames']} frames under rate together: {pooled['nees_mean']:.2f} +- "
        f"{pooled['nees_mean_stderr']:.2f}.",
        "", f"![attitude error and NEES vs rate]({os.path.relpath(images[0], output.parent)})", "",
        "### Where the NEES comes from", "",
        "The published NEES by frame category (mean, frames, tail share; a frame may be in several): a matched spot "
        "flagged saturated, a matched spot flagged blended (split point blend or merged streaks), a matched star "
        f"with another rendered star within {NEIGHBOUR_PX:g} px (truth), none of these.", "",
        "| case | " + " | ".join(CATEGORIES.values()) + " |", "|---|" + "---:|" * len(CATEGORIES),
    ]
    for c in solved:
        by = c["nees_by_category"]
        lines.append(f"| {c['name']} | " + " | ".join(
            f"{by[k]['mean']:.2f} ({by[k]['frames']}, {by[k]['tail_pct']:.1f} %)" if k in by else "-"
            for k in CATEGORIES) + " |")
    lines += [
        "", "Spot chi2: each matched spot against the renderer's true position of its star with the centroider's 2x2 "
        "covariance (expected mean 2). NEES of the same matches refitted (as the identifier: QUEST with isotropic "
        "sigmas, then the maximum-likelihood refinement with each ray's 2-D covariance) with one change each: "
        f"**with the floor** = QUEST with every spot's sigma floored at `centroid_sigma_floor_px` = "
        f"{meta['centroid_sigma_floor_px']} px (what the identifier published before); **isotropic** = QUEST with "
        "the isotropic sigmas only; **no rejection** = every matched star kept (the identifier leaves out stars "
        "beyond 5 sigma); **- clipped** = without spots that have a pixel at the sensor's full-well clip level "
        f"({meta['clip_level_adu']:.0f} ADU, found in the image); **- crowded** = without stars that have another "
        f"rendered star within {NEIGHBOUR_PX:g} px (truth).", "",
        "| case | spot chi2 (2) | isolated, unclipped spots | spots below the floor | clipped spots (frames) | "
        "clipped spots flagged | crowded spots | predicted / measured cross [\"] | predicted / measured roll [\"] | "
        "NEES published | " + " | ".join(VARIANTS.values()) + " |",
        "|---|" + "---:|" * (9 + len(VARIANTS)),
    ]
    for c in solved:
        s = c["stars"]
        flagged = "-" if not np.isfinite(s["clipped_flagged_pct"]) else f"{s['clipped_flagged_pct']:.0f} %"
        lines.append(
            f"| {c['name']} | {s['chi2_mean']:.2f} | {s['chi2_mean_isolated']:.2f} | {s['below_floor_pct']:.0f} % | "
            f"{s['clipped_pct']:.2f} % ({c['clipped_frames_pct']:.1f} %) | {flagged} | {s['crowded_pct']:.1f} % | "
            f"{c['predicted_cross_rms_arcsec']:.2f} / {c['cross_rms_arcsec']:.2f} | "
            f"{c['predicted_roll_rms_arcsec']:.1f} / {c['roll_rms_arcsec']:.1f} | {c['nees_mean']:.2f} | "
            + " | ".join(f"{c[f'{k}_mean']:.2f} ({c[f'{k}_tail_pct']:.1f} %)" for k in VARIANTS) + " |")
    lines += ["", "(NEES variants: mean, and in brackets the tail share above chi2_3(0.997).) Spot chi2 (mean, "
              "expected 2; spot count) by SNR, Hp, distance to the nearest other rendered star and flag:", ""]
    lines += bin_table(solved, "SNR", "chi2_by_snr")
    lines += bin_table(solved, "Hp", "chi2_by_hp")
    lines += bin_table(solved, "neighbour [px]", "chi2_by_neighbour_px")
    flags = list(rest["stars"]["chi2_by_flag"])
    lines += ["| flag | " + " | ".join(flags) + " |", "|---|" + "---:|" * len(flags)]
    for c in solved:
        by = c["stars"]["chi2_by_flag"]
        lines.append(f"| {c['name']} | " + " | ".join(f"{by[f][0]['mean']:.2f} ({by[f][0]['n']})" if by[f] else "-"
                                                      for f in flags) + " |")
    bins = rest["nees_by_star_count"]
    lines += ["", "| stars per frame (rest) | " + " | ".join(f"{r['lo']:g}-{r['hi']:g}".replace("-1000", "+")
                                                             for r in bins) + " |",
              "|---|" + "---:|" * len(bins)]
    for key, label in (("nees", "NEES published"), ("nees_floored", "with the floor"), ("nees_unclipped", "- clipped")):
        by = {r["lo"]: r for r in rest[f"{key}_by_star_count"]}
        lines.append(f"| {label} | " + " | ".join(f"{by[r['lo']]['mean']:.2f} ({by[r['lo']]['n']})" if r["lo"] in by
                                                  else "-" for r in bins) + " |")
    lines += ["", f"![NEES diagnostics]({os.path.relpath(images[1], output.parent)})", ""]
    lines += results.get("findings", [])
    threads = meta.get("engine_run", {}).get("threads", meta.get("jobs"))
    lines += ["", f"Median time per frame [ms] and the case's frame times summed [s] (measured on the workers that ran "
              f"them, {threads} at once on a shared {m['cores']}-core VM: contended, not a latency figure):", "",
              "| case | render | extract_spots | identify | frames [s] |", "|---|---:|---:|---:|---:|"]
    for c in cases:
        t = c["timing_ms"]
        lines.append(f"| {c['name']} | {t['render']:.1f} | {t['centroid']:.1f} | {t['identify']:.2f} | "
                     f"{c.get('frames_s', c.get('elapsed_s', np.nan)):.0f} |")
    return "\n".join(lines) + "\n"


def findings(cases: list[dict], floor_px: float, clip_level: float) -> list[str]:
    """
    Return what this run's numbers show about the covariance, cause by cause.

    Each statement is made only when the numbers show it.
    """
    solved = [c for c in cases if "stars" in c]
    rest = next((c for c in solved if c["kind"] == "rest"), None)
    if rest is None:
        return []
    s = rest["stars"]
    moving = [c for c in solved if c["kind"] != "rest"]
    everything = [rest] + moving
    out = ["Findings:", "",
           f"- The centroider's covariance fits the matched spots: spot chi2 {s['chi2_mean']:.2f} at rest, "
           + ", ".join(f"{c['name']} {c['stars']['chi2_mean']:.2f}" for c in moving)
           + f" (expected 2; isolated, unclipped spots at rest {s['chi2_mean_isolated']:.2f})."]
    out.append(
        f"- Weights: the identifier's attitude fit and published covariance use each spot's own covariance "
        f"(`centroid_sigma_floor_px` = {floor_px} px bounds the matching tolerances only). With the floor in the "
        f"weights, as before, the NEES would be {rest['nees_floored_mean']:.2f} at rest ({s['below_floor_pct']:.0f} % "
        f"of matched spots there have a smaller sigma, median {s['sigma_px_median']:.3f} px); "
        + ", ".join(f"{c['name']} {c['nees_floored_mean']:.2f}" for c in moving) + ".")
    clip = s["chi2_by_flag"]["clipped at full well"]
    if clip:
        missed = s["chi2_by_flag"]["clipped, not flagged"]
        out.append(
            f"- Clipped stars (a pixel within 3 px of the spot at the sensor's {clip_level:.0f} ADU, below the "
            "`saturation_adu` = 0 default of "
            f"65535): {s['clipped_pct']:.2f} % of matched spots at rest ({rest['clipped_frames_pct']:.1f} % of "
            f"frames), {s['clipped_flagged_pct']:.0f} % of them flagged saturated (by a flat top, or by a brightest "
            "pixel far below the fitted model) and fitted without their clipped pixels; chi2 of all clipped spots "
            f"{clip[0]['mean']:.2f} over {clip[0]['n']} (before: ~70, unflagged)"
            + (f", of the unflagged ones {missed[0]['mean']:.2f} over {missed[0]['n']}" if missed else "")
            + ". NEES of frames with a saturated spot: "
            + ", ".join(f"{c['name']} {c['nees_by_category']['saturated']['mean']:.2f} "
                        f"({c['nees_by_category']['saturated']['frames']})"
                        for c in everything if "saturated" in c["nees_by_category"]) + ".")
    near = [c["stars"]["chi2_by_neighbour_px"][0] for c in everything]
    out.append(
        f"- Crowded stars: spots with another rendered star within {near[0]['hi']:g} px still have chi2 "
        + ", ".join(f"{c['name']} {n['mean']:.1f} ({n['n']})" for c, n in zip(everything, near))
        + " (point blends are split at rest, merged streaks on the predicted path under a rate; what remains are "
        "neighbours too faint to split or closer than the PSF). NEES published -> without crowded stars: "
        + ", ".join(f"{c['name']} {c['nees_mean']:.2f} -> {c['nees_isolated_mean']:.2f}" for c in everything) + ".")
    out.append("- Isotropic sigmas alone (QUEST without the 2-D refinement): "
               + ", ".join(f"{c['name']} NEES {c['nees_isotropic_mean']:.2f} (roll {c['nees_isotropic_roll_mean']:.2f})"
                           for c in everything)
               + ". A streak's error is larger along its smear; under a roll rate the smear is along the roll "
               "direction, so isotropic weights understate the roll error. Without the 5-sigma rejection: "
               + ", ".join(f"{c['name']} {c['nees_all_kept_mean']:.2f}" for c in everything) + ".")
    off = [c for c in everything if abs(c["nees_mean"] - GOAL_NEES) > GOAL_NEES_TOLERANCE]
    for c in off:
        z = (c["nees_mean"] - GOAL_NEES) / max(c["nees_mean_stderr"], 1e-9)
        clean = c["nees_by_category"].get("clean")
        out.append(
            f"- {c['name']}: NEES {c['nees_mean']:.2f} is outside {GOAL_NEES:g} +- {GOAL_NEES_TOLERANCE:g} "
            f"({z:+.1f} standard errors from 3 over {c['frames']} frames); frames without saturated, blended or "
            f"crowded stars: {clean['mean']:.2f} ({clean['frames']})." if clean else "")
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000,
                        help="frames at rest (default 1000); each rate case gets half of it (at least 1)")
    parser.add_argument("--jobs", type=int, dest="workers", metavar="J", help="deprecated alias of --workers")
    parser.add_argument("--output", type=Path, help=f"write the '{SECTION}' section of this Markdown file")
    parser.add_argument("--json", type=Path, help="raw numbers (default: bench_attitude.json beside --output)")
    parser.add_argument("--from-json", type=Path, metavar="JSON",
                        help="measure nothing: draw the figures and write the section of --output from these saved "
                             "results")
    add_engine_arguments(parser)
    args = parser.parse_args(argv)
    if args.from_json:
        results = json.loads(args.from_json.read_text())
        if args.output:
            images = figures(results, args.output.parent / "images")
            write_section(args.output, render_markdown(results, images, args.output))
        return
    started = time.perf_counter()
    sensor, identify_config = SensorModel(), IdentifyConfig()
    floor_px = identify_config.centroid_sigma_floor_px
    per_case, failed, run = run_cases(args.frames, args)
    cases, moving_records = [], []
    for index, ((name, kind, rate), records) in enumerate(zip(CASES, per_case)):
        if kind != "rest":
            moving_records += records
        summary = {"name": name, "kind": kind, "rate_deg_s": rate, **summarize(records, floor_px),
                   "failed_frames": sum(f.startswith(f"case {index} ") for f in failed),
                   "frames_s": 1e-3 * sum(r["render_ms"] + r["centroid_ms"] + r["identify_ms"] for r in records)}
        cases.append(summary)
        print(f"{name:>15}: {summary['frames']} frames, {summary['identified_pct']:.1f} % identified, "
              f"cross {summary.get('cross_rms_arcsec', np.nan):.2f}\" roll "
              f"{summary.get('roll_rms_arcsec', np.nan):.1f}\" NEES {summary.get('nees_mean', np.nan):.2f} ("
              + ", ".join(f"{label} {summary.get(key + '_mean', np.nan):.2f}" for key, label in VARIANTS.items())
              + f"); frames {summary['frames_s']:.0f} s", flush=True)
    for line in failed:
        print(f"frame raised: {line}", file=sys.stderr)
    pooled = summarize(moving_records, floor_px)
    command = ("python -m bench.bench_attitude" + (f" --frames {args.frames}" if args.frames != 1000 else "")
               + engine_arguments_text(args) + (f" --output {args.output}" if args.output else ""))
    results = {
        "meta": {"command": command, "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
                 "elapsed_s": time.perf_counter() - started, "machine": machine_info(), "engine": engine_line(run),
                 "engine_run": run, "failed_trials": failed,
                 "seed": SEED, "exposure_s": sensor.exposure_s, "epoch": DatabaseConfig().epoch_jyear,
                 "centroid_sigma_floor_px": floor_px, "chi2_3_997": CHI2_3_997,
                 "clip_level_adu": float(np.floor(sensor.full_well_e / sensor.gain_e_per_adu + sensor.bias_adu + 0.5))},
        "cases": cases,
        "pooled_moving": {key: pooled[key] for key in ("frames", "nees_mean", "nees_mean_stderr", "nees_cross_mean",
                                                       "nees_roll_mean", "nees_tail_pct") if key in pooled},
    }
    results["findings"] = findings(cases, floor_px, results["meta"]["clip_level_adu"])
    print("\n".join(results["findings"]))
    print(f"all rate cases: NEES {pooled.get('nees_mean', np.nan):.2f} +- {pooled.get('nees_mean_stderr', np.nan):.2f}")
    print(engine_line(run) + (f"; {len(failed)} frame(s) raised" if failed else ""))
    json_path = args.json or (args.output.parent / "bench_attitude.json" if args.output else None)
    if json_path:
        json_path.write_text(json.dumps(results, indent=1, default=float) + "\n")
    if args.output:
        images = figures(results, args.output.parent / "images")
        write_section(args.output, render_markdown(results, images, args.output))
        print(f"wrote {args.output} ({SECTION}), {json_path}, {', '.join(map(str, images))}")


if __name__ == "__main__":
    main()
