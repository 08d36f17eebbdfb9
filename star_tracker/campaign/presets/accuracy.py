# SPDX-License-Identifier: Apache-2.0
"""
`accuracy`: rendered frames through the whole chain, the error per axis split into ECSS-E-ST-60-20C's terms.

The trials are nested: `pointings` attitudes uniform over the sphere; at each, `offsets`
attitudes turned by a fraction of a pixel about the sensor's x and y axes (offset 0 is the
pointing itself); at each of those, `repeats` frames that differ only in their noise. Each
frame is rendered (sim/render.py: the default camera and sensor, stars to Hp 7.5, smeared by
`rate_deg_s` across the boresight), centroided (extract_spots, the true rate as its smear
model) and identified lost-in-space; its error d (rotation vector of R_true^T R_est, sensor
frame: x, y across the boresight, z = roll) is recorded with its NEES.

Per axis, the nested analysis of variance splits the error (each term a 1-sigma, and its
3-sigma value, the 99.7 % level of a Gaussian):

- bias: the mean error over every frame;
- temporal noise: the scatter between frames at one attitude (within an offset's repeats);
- pixel spatial error: the scatter of the attitudes' mean errors among sub-pixel offsets of one
  pointing, less what the temporal noise puts there (sub-pixel phase, the detector's
  PRNU/DSNU: the fixed pattern is the sensor's own, the same in every frame);
- FOV spatial error: the scatter of the pointings' mean errors (other stars at other places
  on the detector), less the two terms above; with `distortion_k1` the renderer's lens has a
  radial distortion the identifier's camera model lacks (a calibration residual).

A term whose estimate is below zero (the finer terms explain the scatter) is reported as 0.
With the simulator's defaults there is no bias source (the catalog, the camera model and the
epoch are the identifier's): the bias is then only the terms' residue.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from ...parameter_spec import parameter, range_problems
from ..kind import CampaignKind
from .default_chain import MAGNITUDE_LIMIT, default_chain
from .scoring import ARCSEC, SCORE_COLUMNS, UNSOLVED, score

AXES = ("x", "y", "roll")
TERMS = ("bias", "temporal_noise", "pixel_spatial", "fov_spatial")


@dataclass(frozen=True)
class AccuracyOptions:
    """The nesting, the motion and the calibration residual of an accuracy campaign (each a `parameter`)."""

    pointings: int = parameter(16, "attitudes over the sphere", "", 2, 100000)
    offsets: int = parameter(4, "sub-pixel attitude offsets per pointing", "", 2, 1000)
    repeats: int = parameter(8, "frames per offset (only their noise differs)", "", 2, 1000)
    offset_px: float = parameter(0.5, "largest offset about the sensor's x and y axes", "px", 0.0, 10.0)
    rate_deg_s: float = parameter(0.0, "body rate across the boresight (a direction per pointing)", "deg/s",
                                  0.0, 10.0)
    distortion_k1: float = parameter(0.0, "radial distortion of the rendered lens, unknown to the identifier", "",
                                     -1.0, 1.0)
    pointing_seed: int = parameter(2026, "seed of the pointings and offsets (the campaign's seed draws the noise)",
                                   "", 0, 2 ** 31)
    wrong_arcsec: float = parameter(60.0, "a boresight this far from the truth is wrong", "arcsec", 0.0, 1e6,
                                    low_open=True)

    def __post_init__(self) -> None:
        bad = range_problems(self)
        if bad:
            raise ValueError("accuracy options: " + "; ".join(bad))

    @property
    def trials(self) -> int:
        return self.pointings * self.offsets * self.repeats


@dataclass
class _Shared:
    camera: object
    renderer: object
    identifier: object
    centroid: object
    exposure_s: float


def trial_attitude(options: AccuracyOptions, task: int) -> tuple[int, int, int, np.ndarray, np.ndarray]:
    """Return (pointing, offset, repeat, R sensor->ICRS, body rate [rad/s, sensor]) of trial `task`."""
    from ...models.attitude import quaternion_to_matrix, rotation_vector_to_matrix
    from ...models.camera import CameraModel

    per_pointing = options.offsets * options.repeats
    pointing, offset, repeat = task // per_pointing, (task // options.repeats) % options.offsets, task % options.repeats
    draw = np.random.default_rng([options.pointing_seed, pointing])
    rotation = quaternion_to_matrix(draw.normal(size=4))
    azimuth = draw.uniform(0.0, 2.0 * math.pi)
    rate = math.radians(options.rate_deg_s) * np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
    if offset:
        pixel = CameraModel.from_fov(1024, 1024, math.radians(15.0)).pixel_scale_rad
        turn = np.random.default_rng([options.pointing_seed, pointing, offset]).uniform(-1.0, 1.0, 2)
        rotation = rotation @ rotation_vector_to_matrix([*(turn * options.offset_px * pixel), 0.0])
    return pointing, offset, repeat, rotation, rate


class Accuracy(CampaignKind):
    """Rendered frames split into the ECSS error terms (module docstring)."""

    name = "accuracy"
    description = "rendered frames through the chain: error per axis as bias, temporal noise, pixel and FOV spatial"
    options_type = AccuracyOptions
    default_trials = 0  # the options' nesting: pointings x offsets x repeats
    default_batch = 16
    columns = (pa.field("pointing", pa.int32()), pa.field("offset", pa.int32()), pa.field("repeat", pa.int32()),
               pa.field("solved", pa.bool_()), *SCORE_COLUMNS, pa.field("error_x_arcsec", pa.float64()),
               pa.field("error_y_arcsec", pa.float64()), pa.field("error_roll_arcsec", pa.float64()),
               pa.field("matched", pa.int32()), pa.field("spots", pa.int32()), pa.field("frame_s", pa.float64()))

    def prepare(self, options: AccuracyOptions) -> _Shared:
        from ...centroid import CentroidConfig
        from ...models.camera import CameraModel
        from ...sim.render import StarFieldRenderer

        chain = default_chain()
        lens = CameraModel.from_fov(1024, 1024, math.radians(15.0), (options.distortion_k1, 0.0, 0.0, 0.0, 0.0))
        chain.identifier.warm_up(chain.camera)
        renderer = StarFieldRenderer(lens, chain.sensor, chain.catalog, magnitude_limit=MAGNITUDE_LIMIT)
        return _Shared(chain.camera, renderer, chain.identifier, CentroidConfig(), chain.sensor.exposure_s)

    def trial(self, shared: _Shared, options: AccuracyOptions, task: int, rng: np.random.Generator) -> dict:
        from ...centroid import extract_spots
        from ...centroid.streak.smear import SmearModel
        from ...models.attitude import matrix_to_rotation_vector
        from ...sim.motion import ConstantRateMotion

        pointing, offset, repeat, rotation, rate = trial_attitude(options, task)
        started = time.perf_counter()
        frame = shared.renderer.render(ConstantRateMotion(rotation, rate), 0.0, int(rng.integers(2 ** 31)))
        spots = extract_spots(frame.image, shared.centroid, SmearModel(shared.camera, rate, shared.exposure_s))
        result = shared.identifier.identify(spots, shared.camera)
        record = {"pointing": pointing, "offset": offset, "repeat": repeat, "solved": result.solved, **UNSOLVED,
                  "error_x_arcsec": None, "error_y_arcsec": None, "error_roll_arcsec": None,
                  "matched": int(result.hip.size) if result.solved else 0, "spots": len(spots),
                  "frame_s": time.perf_counter() - started}
        if result.solved:
            truth = frame.truth.rotation
            record.update(score(result, truth_hip(frame.truth, spots, result), truth, options.wrong_arcsec))
            error = matrix_to_rotation_vector(truth.T @ result.attitude.rotation) / ARCSEC
            record.update(error_x_arcsec=float(error[0]), error_y_arcsec=float(error[1]),
                          error_roll_arcsec=float(error[2]))
        return record

    def summarize(self, table: pa.Table, options: AccuracyOptions) -> dict:
        ok = np.asarray(table.column("error").to_pylist(), object) == ""
        solved = np.asarray(table.column("solved").fill_null(False), bool) & ok
        wrong = np.asarray(table.column("wrong").fill_null(False), bool) & ok
        right = solved & ~wrong
        nees = np.asarray(table.column("nees").fill_null(np.nan), float)[right]
        groups = (np.asarray(table.column("pointing").fill_null(-1))[right],
                  np.asarray(table.column("offset").fill_null(-1))[right])
        axes = {}
        for axis in AXES:
            error = np.asarray(table.column(f"error_{axis}_arcsec").fill_null(np.nan), float)[right]
            axes[axis] = {**error_terms(error, *groups), "rms": _rms(error),
                          "p997": float(np.quantile(np.abs(error), 0.997)) if error.size else None}
        flags = {name: int((np.asarray(table.column(name).fill_null(False), bool) & ok).sum())
                 for name in ("false_identification", "wrong_deep_star")}
        return {"trials": int(ok.sum()), "solved": int(solved.sum()), "wrong": int(wrong.sum()), **flags,
                "failed_tasks": int((~ok).sum()), "nees_mean": float(np.mean(nees)) if nees.size else None,
                "axes": axes, "rate_deg_s": options.rate_deg_s, "distortion_k1": options.distortion_k1,
                "frame_ms_median": float(np.median(np.asarray(table.column("frame_s").fill_null(np.nan))[ok]) * 1e3)
                if ok.any() else None}


# A spot is its star's when the star lies within TRUTH_PX of it, or when the star is the one
# named (else the rendered star nearest the spot) and within TRUTH_CHI2 (5 sigma in 2-D) of
# the spot's own covariance: a faint 27 px streak's along-track sigma is ~1 px, so its own
# star can lie 3-5 px off (the 3 px rule alone called 144 of 256 frames at 4 deg/s wrong,
# every one such a star).
TRUTH_PX = 3.0
TRUTH_CHI2 = 25.0
# A spot is a blend of the stars within BLEND_PX of it when their light centre (weighted by
# their signal) is where the spot is (TRUTH_PX, or TRUTH_CHI2 of its covariance): two stars
# 6.3 px apart under a 2.7 px PSF smear into one streak whose centre is 3.1 and 3.3 px from
# either (stress campaign, seed 2026, task 275); the star named is then right when it is one of
# them.
BLEND_PX = 2.0 * TRUTH_PX


def truth_hip(truth, spots, result) -> np.ndarray:
    """Return the HIP id of the rendered star behind each matched spot (0: none), for the scoring."""
    from ...sim.render import KIND_STAR

    hip = np.zeros(len(spots), np.int64)
    star = truth.kind == KIND_STAR
    sx, sy, shp = truth.x[star], truth.y[star], truth.hip[star]
    if shp.size == 0:
        return hip
    for i in np.asarray(result.spot_index, np.int64):
        distance = np.hypot(sx - spots.x[i], sy - spots.y[i])
        if distance.min() <= TRUTH_PX:
            # The star it was named after when that one is among the close ones (blends), else the nearest.
            named = int(result.hip[np.flatnonzero(result.spot_index == i)[0]])
            close = shp[distance <= TRUTH_PX]
            hip[i] = named if named in close else int(shp[np.argmin(distance)])
            continue
        # Beyond TRUTH_PX: the star named when its spot's covariance holds it (a streak blended
        # from two stars is as near one as the other: stress campaign, seed 2026, task 672), else
        # the nearest star when the covariance holds that one, else a blend (BLEND_PX).
        named = int(result.hip[np.flatnonzero(result.spot_index == i)[0]])
        for j in (np.flatnonzero(shp == named)[:1].tolist() + [int(np.argmin(distance))]):
            if _holds(spots, i, sx[j], sy[j]):
                hip[i] = int(shp[j])
                break
        else:
            blend = distance <= BLEND_PX
            if np.count_nonzero(blend) >= 2:
                signal = np.asarray(truth.electrons, float)[star][blend]
                weight = signal / signal.sum()
                if _holds(spots, i, float(weight @ sx[blend]), float(weight @ sy[blend])):
                    hip[i] = named if named in shp[blend] else int(shp[blend][np.argmax(signal)])
    return hip


def _holds(spots, i: int, x: float, y: float) -> bool:
    """Whether (x, y) [px] lies within TRUTH_PX of spot i or TRUTH_CHI2 of its covariance."""
    offset = np.array([x - spots.x[i], y - spots.y[i]])
    return bool(np.hypot(*offset) <= TRUTH_PX or float(offset @ np.linalg.solve(spots.cov[i], offset)) <= TRUTH_CHI2)


def _rms(values: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(values ** 2))) if values.size else None


def error_terms(error: np.ndarray, pointing: np.ndarray, offset: np.ndarray) -> dict:
    """
    Return the nested variance split of one axis's errors [arcsec] (module docstring), 1-sigma each.

    error, pointing, offset: per frame. Each term's variance is the spread at its level less the
    finer terms' share in it (method of moments); a negative estimate is reported as 0.
    """
    if error.size < 2:
        return {term: None for term in TERMS}
    cells: dict[tuple[int, int], list[float]] = {}
    for e, p, o in zip(error, pointing, offset):
        cells.setdefault((int(p), int(o)), []).append(float(e))
    within = [np.var(v, ddof=1) for v in cells.values() if len(v) > 1]
    temporal = float(np.mean(within)) if within else 0.0
    repeats = float(np.mean([len(v) for v in cells.values()]))
    cell_mean = {k: float(np.mean(v)) for k, v in cells.items()}
    by_pointing: dict[int, list[float]] = {}
    for (p, _), m in cell_mean.items():
        by_pointing.setdefault(p, []).append(m)
    among_offsets = [np.var(v, ddof=1) for v in by_pointing.values() if len(v) > 1]
    pixel = max(float(np.mean(among_offsets)) - temporal / repeats, 0.0) if among_offsets else 0.0
    offsets = float(np.mean([len(v) for v in by_pointing.values()]))
    pointing_mean = [float(np.mean(v)) for v in by_pointing.values()]
    fov = (max(float(np.var(pointing_mean, ddof=1)) - pixel / offsets - temporal / (offsets * repeats), 0.0)
           if len(pointing_mean) > 1 else 0.0)
    return {"bias": float(np.mean(error)), "temporal_noise": math.sqrt(temporal), "pixel_spatial": math.sqrt(pixel),
            "fov_spatial": math.sqrt(fov)}
