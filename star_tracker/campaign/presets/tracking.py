# SPDX-License-Identifier: Apache-2.0
"""
`tracking`: frame sequences through render -> centroid -> track over a grid of rate and acceleration: the envelope.

Case c of the grid is (rate, acceleration) = (rates_deg_s[c // A], accelerations_deg_s2[c % A]),
A accelerations; trial t runs case t // runs. A trial is an eigen-axis slew (sim/motion.py
SlewMotion: a random pointing, an axis across the boresight with a little roll) that rests
0.5 s, accelerates at the case's acceleration to the case's rate and coasts, rendered at 10 Hz
for `frames` frames (the default camera and sensor, 0.1 s exposures, stars to Hp 7.5). Each
frame is centroided with the tracker's own rate and angular acceleration, carried to the frame,
as its smear model (the node's rate aid) and
handed to `Tracker.process` (tracking, lost-in-space when it fails). A frame is right when
solved with every star right and its boresight within `wrong_arcsec` (60") of the truth; a
solved frame whose error lies outside 5 sigma of its stated covariance is counted
overconfident beside (scoring.py; the covariance under angular acceleration is a known
limit). The trial records its frames right, wrong, overconfident and lost after the first
solve, the errors, the NEES and the rate at the first loss; beside, the solved frames split by
phase: accelerating (the body's rate changes within the exposure, in the truth) or steady (at
rest or coasting), each with its count, its overconfident frames and its NEES sum, so the
summary says where an overconfident covariance comes from. The summary is the envelope: per
case the share of frames right, and per acceleration the fastest rate reached (a sequence
may end before its coast rate) with every frame tracked right in it and in every slower case.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from ...parameter_spec import parameter, range_problems
from ..kind import CampaignKind
from .accuracy import truth_hip
from .default_chain import MAGNITUDE_LIMIT, default_chain
from .scoring import NEES_5_SIGMA, score

PERIOD_S = 0.1
REST_S = 0.5
PHASES = ("accelerating", "steady")
STEADY_RATE_CHANGE_RAD_S = 1e-9  # a rate change within the exposure below this is steady motion


def _numbers(text: str, name: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise ValueError(f"{name}={text!r}: expected numbers separated by commas") from None
    if not values or any(not v > 0 for v in values):
        raise ValueError(f"{name}={text!r}: expected positive numbers separated by commas")
    return values


@dataclass(frozen=True)
class TrackingOptions:
    """The grid and the sequences of a tracking campaign (each a `parameter`)."""

    rates_deg_s: str = parameter("1,2,3,4,5,6", "coast rates of the grid, comma-separated", "deg/s")
    accelerations_deg_s2: str = parameter("1,2,4", "accelerations of the grid, comma-separated", "deg/s^2")
    runs: int = parameter(3, "sequences per case", "", 1, 100000)
    frames: int = parameter(60, "frames per sequence (10 Hz; the rate reached is reported)", "", 5, 100000)
    wrong_arcsec: float = parameter(60.0, "a boresight this far from the truth is wrong", "arcsec", 0.0, 1e6,
                                    low_open=True)

    def __post_init__(self) -> None:
        bad = range_problems(self)
        for name in ("rates_deg_s", "accelerations_deg_s2"):
            try:
                _numbers(getattr(self, name), name)
            except ValueError as exc:
                bad.append(str(exc))
        if bad:
            raise ValueError("tracking options: " + "; ".join(bad))

    @property
    def rates(self) -> tuple[float, ...]:
        return _numbers(self.rates_deg_s, "rates_deg_s")

    @property
    def accelerations(self) -> tuple[float, ...]:
        return _numbers(self.accelerations_deg_s2, "accelerations_deg_s2")

    @property
    def trials(self) -> int:
        return len(self.rates) * len(self.accelerations) * self.runs


@dataclass
class _Shared:
    camera: object
    renderer: object
    lost_in_space: object
    exposure_s: float


class Tracking(CampaignKind):
    """Sequences over a grid of rate and acceleration (module docstring)."""

    name = "tracking"
    description = "frame sequences over a grid of rate and acceleration: the tracking envelope"
    options_type = TrackingOptions
    default_trials = 0  # the grid: rates x accelerations x runs
    default_batch = 1
    columns = (pa.field("rate_deg_s", pa.float64()), pa.field("acceleration_deg_s2", pa.float64()),
               pa.field("frames", pa.int32()), pa.field("first_solved", pa.int32()), pa.field("right", pa.int32()),
               pa.field("wrong", pa.int32()), pa.field("lost", pa.int32()), pa.field("overconfident", pa.int32()),
               pa.field("tracked", pa.int32()), pa.field("cross_arcsec_rms", pa.float64()),
               pa.field("cross_arcsec_max", pa.float64()), pa.field("nees_mean", pa.float64()),
               pa.field("first_loss_rate_deg_s", pa.float64()), pa.field("reached_rate_deg_s", pa.float64()),
               pa.field("frame_s", pa.float64()),
               *(pa.field(f"{phase}_{what}", kind) for phase in PHASES
                 for what, kind in (("frames", pa.int32()), ("overconfident", pa.int32()), ("nees_sum", pa.float64()))))

    def prepare(self, options: TrackingOptions) -> _Shared:
        from ...sim.render import StarFieldRenderer
        from ...track.tracking import Tracker

        chain = default_chain()
        Tracker(chain.identifier).warm_up(chain.camera)
        renderer = StarFieldRenderer(chain.camera, chain.sensor, chain.catalog, magnitude_limit=MAGNITUDE_LIMIT)
        return _Shared(chain.camera, renderer, chain.identifier, chain.sensor.exposure_s)

    def trial(self, shared: _Shared, options: TrackingOptions, task: int, rng: np.random.Generator) -> dict:
        from ...centroid import CentroidConfig, extract_spots
        from ...models.attitude import quaternion_to_matrix
        from ...sim.motion import SlewMotion
        from ...track.tracking import MODE_TRACKING, Tracker

        case = task // options.runs
        accelerations = options.accelerations
        rate, acceleration = options.rates[case // len(accelerations)], accelerations[case % len(accelerations)]
        azimuth = rng.uniform(0.0, 2.0 * math.pi)
        axis = np.array([math.cos(azimuth), math.sin(azimuth), rng.uniform(-0.3, 0.3)])
        motion = SlewMotion(quaternion_to_matrix(rng.normal(size=4)), axis, angle_rad=math.radians(360.0),
                            max_rate_rad_s=math.radians(rate), accel_rad_s2=math.radians(acceleration),
                            t_start=REST_S)
        tracker = Tracker(shared.lost_in_space)
        started = time.perf_counter()
        right = wrong = lost = overconfident = tracked = 0
        first_solved, first_loss_rate, cross, nees, reached = -1, None, [], [], 0.0
        by_phase = {phase: [0, 0, 0.0] for phase in PHASES}  # frames, overconfident, NEES sum
        for k in range(options.frames):
            t = 0.05 + PERIOD_S * k
            frame = shared.renderer.render(motion, t, int(rng.integers(2 ** 31)))
            reached = max(reached, math.degrees(float(np.linalg.norm(frame.truth.body_rate))))
            stamp_ns = int(round(t * 1e9))
            # The tracker's rate and acceleration carried to the frame, as the centroider takes them.
            smear = tracker.centroider_aid(stamp_ns, shared.camera, shared.exposure_s)
            spots = extract_spots(frame.image, CentroidConfig(), smear)
            result = tracker.process(stamp_ns, spots, shared.camera)
            ident = result.identification
            if ident.solved:
                scored = score(ident, truth_hip(frame.truth, spots, ident), frame.truth.rotation,
                               options.wrong_arcsec)
                first_solved = k if first_solved < 0 else first_solved
                bad = scored["wrong_star"] or scored["cross_arcsec"] > options.wrong_arcsec
                wrong += bad
                right += not bad
                overconfident += scored["nees"] > NEES_5_SIGMA
                tracked += result.mode == MODE_TRACKING
                cross.append(scored["cross_arcsec"])
                nees.append(scored["nees"])
                change = motion.angular_velocity_at(t + 0.5 * shared.exposure_s) \
                    - motion.angular_velocity_at(t - 0.5 * shared.exposure_s)
                tally = by_phase[PHASES[0] if np.linalg.norm(change) > STEADY_RATE_CHANGE_RAD_S else PHASES[1]]
                tally[0] += 1
                tally[1] += scored["nees"] > NEES_5_SIGMA
                tally[2] += scored["nees"]
            elif first_solved >= 0:
                lost += 1
                if first_loss_rate is None:
                    first_loss_rate = math.degrees(float(np.linalg.norm(frame.truth.body_rate)))
        cross_a, nees_a = np.asarray(cross), np.asarray(nees)
        return {"rate_deg_s": rate, "acceleration_deg_s2": acceleration, "frames": options.frames,
                "first_solved": first_solved, "right": right, "wrong": wrong, "lost": lost,
                "overconfident": overconfident, "tracked": tracked,
                "cross_arcsec_rms": float(np.sqrt(np.mean(cross_a ** 2))) if cross_a.size else None,
                "cross_arcsec_max": float(cross_a.max()) if cross_a.size else None,
                "nees_mean": float(nees_a.mean()) if nees_a.size else None,
                "first_loss_rate_deg_s": first_loss_rate, "reached_rate_deg_s": reached,
                "frame_s": (time.perf_counter() - started) / options.frames,
                **{f"{phase}_{what}": value for phase, tally in by_phase.items()
                   for what, value in zip(("frames", "overconfident", "nees_sum"), tally)}}

    def summarize(self, table: pa.Table, options: TrackingOptions) -> dict:
        ok = np.asarray(table.column("error").to_pylist(), object) == ""
        col = {name: np.asarray(table.column(name).fill_null(0), float)[ok]
               for name in ("rate_deg_s", "acceleration_deg_s2", "frames", "first_solved", "right", "wrong", "lost",
                            "overconfident", "tracked")}
        nees = np.asarray(table.column("nees_mean").fill_null(np.nan), float)[ok]
        cases = []
        for rate in options.rates:
            for acceleration in options.accelerations:
                mine = (col["rate_deg_s"] == rate) & (col["acceleration_deg_s2"] == acceleration)
                reached = np.asarray(table.column("reached_rate_deg_s").fill_null(0.0), float)[ok][mine]
                after = np.maximum(col["frames"][mine] - np.maximum(col["first_solved"][mine], 0), 0)
                judged = float(after.sum())
                cases.append({"rate_deg_s": rate, "acceleration_deg_s2": acceleration, "runs": int(mine.sum()),
                              "reached_rate_deg_s": float(reached.min()) if reached.size else None,
                              "frames_after_acquisition": int(judged),
                              "right_share": float(col["right"][mine].sum() / judged) if judged else None,
                              "wrong": int(col["wrong"][mine].sum()), "lost": int(col["lost"][mine].sum()),
                              "overconfident": int(col["overconfident"][mine].sum()),
                              "tracked_share": float(col["tracked"][mine].sum() / judged) if judged else None,
                              "nees_mean": float(np.nanmean(nees[mine])) if np.isfinite(nees[mine]).any() else None})
        envelope = {}
        for acceleration in options.accelerations:
            # The envelope ends at the slowest case that failed: a faster one that held does not extend it.
            held = None
            for case in sorted((c for c in cases if c["acceleration_deg_s2"] == acceleration),
                               key=lambda c: c["rate_deg_s"]):
                if case["right_share"] != 1.0 or case["wrong"] or case["reached_rate_deg_s"] is None:
                    break
                held = case["reached_rate_deg_s"]
            envelope[f"{acceleration:g}"] = round(held, 2) if held is not None else None
        phases = {}
        for phase in PHASES:
            frames = int(np.asarray(table.column(f"{phase}_frames").fill_null(0), float)[ok].sum())
            nees_sum = float(np.asarray(table.column(f"{phase}_nees_sum").fill_null(0.0), float)[ok].sum())
            phases[phase] = {"frames": frames,
                             "overconfident": int(np.asarray(table.column(f"{phase}_overconfident").fill_null(0),
                                                             float)[ok].sum()),
                             "nees_mean": nees_sum / frames if frames else None}
        return {"trials": int(ok.sum()), "failed_tasks": int((~ok).sum()), "phases": phases,
                "frames": int(col["frames"].sum()), "wrong_frames": int(col["wrong"].sum()),
                "overconfident_frames": int(col["overconfident"].sum()),
                "cases": cases, "envelope_rate_deg_s_by_acceleration": envelope}
