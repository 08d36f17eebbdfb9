# SPDX-License-Identifier: Apache-2.0
"""
`robustness`: lost-in-space on rendered frames while one stress at a time rises.

Five sweeps, each over STRESS_LEVELS's levels with every other setting at the simulator's
defaults (the default camera and sensor, stars to Hp 7.5, at rest):

- `false_objects`: bright non-catalog points per frame (FalseObjectModel.planets_per_frame,
  instrument magnitudes -1 to 2);
- `hot_pixels`: the fraction of hot pixels (SensorModel.hot_pixel_fraction, 200x the dark
  current; the pattern is the sensor's own, the same in every frame);
- `cosmic_rays`: hits per cm^2 per second (SensorModel.cosmic_ray_rate_per_cm2_s, 3000 e- each;
  ~5 /cm^2/s in a quiet orbit, 100x that in the South Atlantic Anomaly);
- `temperature`: the detector temperature [K] (the dark current doubles every 6 K from 20 e-/px/s
  at 20 C);
- `stray_light`: the sky + stray-light background [e-/px/s], rising by half of itself from the
  image centre to the half diagonal toward +x (the simulator's stray-light plane).

Each trial: a random attitude uniform over the sphere, `frames` frames per level, rendered
(sim/render.py), centroided (extract_spots) and identified lost-in-space by the default
identifier, scored (scoring.py: wrong = a star named wrongly, a boresight more than
`wrong_arcsec` off, or an error outside 5 sigma of the stated covariance). The summary gives,
per sweep and level, the trials, the share solved right, the wrong ones with their 95 % upper
bound (of them the false identifications, and the errors beyond 5 sigma of the stated
covariance), and the median cross-boresight and roll errors.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
import pyarrow as pa

from ...parameter_spec import parameter, range_problems
from ..bounds import rate_upper_bound
from ..kind import CampaignKind
from .accuracy import truth_hip
from .default_chain import MAGNITUDE_LIMIT, default_chain
from .scoring import NEES_5_SIGMA, SCORE_COLUMNS, UNSOLVED, score

# Each sweep's levels; the first is the simulator's default (no stress).
STRESS_LEVELS = {
    "false_objects": (0, 5, 10, 20, 50),
    "hot_pixels": (0.0, 1e-4, 1e-3, 3e-3, 1e-2),
    "cosmic_rays": (0.0, 5.0, 50.0, 500.0, 5000.0),
    "temperature": (293.15, 313.15, 333.15, 343.15, 353.15),
    "stray_light": (400.0, 1e4, 5e4, 1e5, 2e5),
}
STRESS_UNITS = {"false_objects": "per frame", "hot_pixels": "fraction", "cosmic_rays": "1/cm^2/s",
                "temperature": "K", "stray_light": "e-/px/s"}
STRAY_LIGHT_RISE = 0.5  # relative, from the image centre to the half diagonal


@dataclass(frozen=True)
class RobustnessOptions:
    """The sweeps of a robustness campaign (each a `parameter`)."""

    frames: int = parameter(32, "frames per sweep level", "", 1, 1000000)
    sweeps: str = parameter(",".join(STRESS_LEVELS), "the sweeps to run, comma-separated")
    wrong_arcsec: float = parameter(60.0, "a boresight this far from the truth is wrong", "arcsec", 0.0, 1e6,
                                    low_open=True)

    def __post_init__(self) -> None:
        bad = range_problems(self)
        names = [s.strip() for s in self.sweeps.split(",") if s.strip()]
        unknown = [s for s in names if s not in STRESS_LEVELS]
        if not names or unknown:
            bad.append(f"sweeps={self.sweeps!r}: choose among {', '.join(STRESS_LEVELS)}")
        if bad:
            raise ValueError("robustness options: " + "; ".join(bad))

    @property
    def cases(self) -> tuple[tuple[str, float], ...]:
        """Return every (sweep, level) in order: the trials' cells, `frames` trials each."""
        names = [s.strip() for s in self.sweeps.split(",") if s.strip()]
        return tuple((s, level) for s in names for level in STRESS_LEVELS[s])

    @property
    def trials(self) -> int:
        return len(self.cases) * self.frames


@dataclass
class _Shared:
    camera: object
    sensor: object
    catalog: object
    identifier: object
    centroid: object
    renderers: dict


def stressed_models(sweep: str, level: float, sensor):
    """Return (SensorModel, FalseObjectModel) of one sweep level, everything else the defaults."""
    from ...sim.render import FalseObjectModel

    objects = FalseObjectModel()
    if sweep == "false_objects":
        objects = FalseObjectModel(planets_per_frame=int(level))
    elif sweep == "hot_pixels":
        sensor = replace(sensor, hot_pixel_fraction=float(level))
    elif sweep == "cosmic_rays":
        sensor = replace(sensor, cosmic_ray_rate_per_cm2_s=float(level))
    elif sweep == "temperature":
        sensor = replace(sensor, temperature_k=float(level))
    elif sweep == "stray_light":
        half_diagonal = math.hypot(512.0, 512.0)
        sensor = replace(sensor, background_e_per_px_s=float(level),
                         stray_light_gradient_e_per_px2_s=(STRAY_LIGHT_RISE * float(level) / half_diagonal, 0.0))
    return sensor, objects


class Robustness(CampaignKind):
    """Lost-in-space while one stress rises (module docstring)."""

    name = "robustness"
    description = "rendered frames solved lost-in-space while false objects, hot pixels, cosmic rays, temperature " \
                  "or stray light rise"
    options_type = RobustnessOptions
    default_trials = 0  # the sweeps: levels x frames
    default_batch = 8
    columns = (pa.field("sweep", pa.string()), pa.field("level", pa.float64()), pa.field("solved", pa.bool_()),
               *SCORE_COLUMNS, pa.field("matched", pa.int32()), pa.field("spots", pa.int32()),
               pa.field("frame_s", pa.float64()))

    def prepare(self, options: RobustnessOptions) -> _Shared:
        from ...centroid import CentroidConfig

        chain = default_chain()
        chain.identifier.warm_up(chain.camera)
        return _Shared(chain.camera, chain.sensor, chain.catalog, chain.identifier, CentroidConfig(), {})

    def _renderer(self, shared: _Shared, sweep: str, level: float):
        from ...sim.render import StarFieldRenderer

        key = (sweep, level)
        if key not in shared.renderers:
            sensor, objects = stressed_models(sweep, level, shared.sensor)
            shared.renderers[key] = StarFieldRenderer(shared.camera, sensor, shared.catalog,
                                                      magnitude_limit=MAGNITUDE_LIMIT, false_objects=objects)
        return shared.renderers[key]

    def trial(self, shared: _Shared, options: RobustnessOptions, task: int, rng: np.random.Generator) -> dict:
        from ...centroid import extract_spots
        from ...models.attitude import quaternion_to_matrix
        from ...sim.motion import ConstantRateMotion

        sweep, level = options.cases[task // options.frames]
        renderer = self._renderer(shared, sweep, level)
        rotation = quaternion_to_matrix(rng.normal(size=4))
        started = time.perf_counter()
        frame = renderer.render(ConstantRateMotion(rotation, np.zeros(3)), 0.0, int(rng.integers(2 ** 31)))
        spots = extract_spots(frame.image, shared.centroid)
        result = shared.identifier.identify(spots, shared.camera)
        record = {"sweep": sweep, "level": float(level), "solved": result.solved, **UNSOLVED,
                  "matched": int(result.hip.size) if result.solved else 0, "spots": len(spots),
                  "frame_s": time.perf_counter() - started}
        if result.solved:
            record.update(score(result, truth_hip(frame.truth, spots, result), frame.truth.rotation,
                                options.wrong_arcsec))
        return record

    def summarize(self, table: pa.Table, options: RobustnessOptions) -> dict:
        ok = np.asarray(table.column("error").to_pylist(), object) == ""
        sweep = np.asarray(table.column("sweep").fill_null("").to_pylist(), object)
        level = np.asarray(table.column("level").fill_null(np.nan), float)
        solved = np.asarray(table.column("solved").fill_null(False), bool) & ok
        wrong = np.asarray(table.column("wrong").fill_null(False), bool) & ok
        cross = np.asarray(table.column("cross_arcsec").fill_null(np.nan), float)
        roll = np.asarray(table.column("roll_arcsec").fill_null(np.nan), float)
        nees = np.asarray(table.column("nees").fill_null(np.nan), float)
        false_id = np.asarray(table.column("false_identification").fill_null(False), bool) & ok
        sweeps: dict[str, list[dict]] = {}
        for name, value in options.cases:
            cell = ok & (sweep == name) & (level == float(value))
            right = cell & solved & ~wrong
            n, bad = int(cell.sum()), int((cell & wrong).sum())
            sweeps.setdefault(name, []).append({
                "level": float(value), "trials": n, "solved_right": int(right.sum()),
                "availability": float(right.sum() / n) if n else None, "wrong": bad,
                "wrong_upper_95": rate_upper_bound(bad, n) if n else None,
                "cross_arcsec_median": float(np.median(cross[right])) if right.any() else None,
                "roll_arcsec_median": float(np.median(roll[right])) if right.any() else None,
                "false_identification": int((cell & false_id).sum()),
                "outside_5_sigma": int(np.sum(nees[cell & solved] > NEES_5_SIGMA))})
        return {"trials": int(ok.sum()), "solved": int(solved.sum()), "wrong": int(wrong.sum()),
                "failed_tasks": int((~ok).sum()), "units": {s: STRESS_UNITS[s] for s in sweeps}, "sweeps": sweeps}
