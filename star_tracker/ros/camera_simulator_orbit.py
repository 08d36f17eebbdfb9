# SPDX-License-Identifier: Apache-2.0
"""
camera_simulator in orbit: its orbit, head and environment parameters, and the spacecraft they build (ROS-free).

`orbit.model`: "none" (today's camera somewhere in inertial space, no environment), "kepler"
(elements; `orbit.sun_synchronous` sets the inclination from the altitude), "tle" (two lines,
SGP4) or "external" (the spacecraft's state from `truth_in/odometry`, a user's own propagator).
The attitude profile (attitude.*) moves the **body**; the head (the camera) sits on it with
`head.mounting_quaternion` (orientation of the head frame in the body frame, x, y, z, w, as tf:
v_body = R(q) v_head; identity by default, so without a mounting the body is the camera), and
optionally a true misalignment (`head.misalignment_rad`, a thermo-elastic drift). With an
orbit, two more profiles: "nadir" (LVLH: body +Z to nadir, +X along the velocity) and
"sun_pointing" (body +Z at the Sun). `environment.*` switches and tunes what the Sun, the
Earth, the Moon and the planets do to each frame (sim.environment.EnvironmentModel), with the
heads' exclusion angles (`environment.exclusion.*`).

Stamps are the orbit's time: the node's clock (UNIX time, read as UTC by the ephemeris; ROS sim
time runs a scenario faster than real time). The elements' epoch is `orbit.epoch_utc` (ISO 8601)
or, empty, the first exposure's stamp. Bad values raise ValueError naming the parameter: the
node refuses to configure and stays unconfigured.
"""
from __future__ import annotations

import datetime
import math
from dataclasses import dataclass

import numpy as np

from ..models.sky_geometry import ExclusionModel
from ..parameter_spec import ParameterSpec, field_specs, field_values
from ..sim.environment import EnvironmentModel

ORBIT_MODELS = ("none", "kepler", "tle", "external")
ORBIT_PROFILES = ("nadir", "sun_pointing")  # body attitude modes that need an orbit
ENVIRONMENT_PARAMETERS = field_specs(EnvironmentModel, prefix="environment.")  # its exclusion: below
EXCLUSION_PARAMETERS = field_specs(ExclusionModel, prefix="environment.exclusion.")
ORBIT_PARAMETERS = [
    ParameterSpec("orbit.model", "none", "the spacecraft's orbit: none = a camera at rest in inertial space, no "
                  "environment; kepler = orbit.* elements; tle = orbit.tle_line1/2 (SGP4); external = "
                  "truth_in/odometry", choices=ORBIT_MODELS),
    ParameterSpec("orbit.altitude_m", 550e3, "circular-equivalent altitude (semi-major axis minus the Earth's "
                  "equatorial radius)", "m", 100e3, 1e9),
    ParameterSpec("orbit.eccentricity", 0.0, "eccentricity", "", 0.0, 0.99),
    ParameterSpec("orbit.inclination_deg", 97.6, "inclination (ignored with orbit.sun_synchronous)", "deg",
                  0.0, 180.0),
    ParameterSpec("orbit.sun_synchronous", True, "set the inclination for a sun-synchronous orbit at "
                  "orbit.altitude_m"),
    ParameterSpec("orbit.raan_deg", 0.0, "right ascension of the ascending node", "deg", -360.0, 360.0),
    ParameterSpec("orbit.arg_perigee_deg", 0.0, "argument of perigee", "deg", -360.0, 360.0),
    ParameterSpec("orbit.true_anomaly_deg", 0.0, "true anomaly at the epoch", "deg", -360.0, 360.0),
    ParameterSpec("orbit.epoch_utc", "", "epoch of the elements, ISO 8601 UTC (e.g. 2026-12-01T00:00:00); empty = "
                  "the first exposure"),
    ParameterSpec("orbit.tle_line1", "", "TLE line 1 (orbit.model tle)"),
    ParameterSpec("orbit.tle_line2", "", "TLE line 2 (orbit.model tle)"),
    ParameterSpec("head.mounting_quaternion", (0.0, 0.0, 0.0, 1.0), "orientation (x, y, z, w) of this head (the "
                  "camera frame) in the body frame: v_body = R(q) v_head; the attitude profile moves the body"),
    ParameterSpec("head.misalignment_rad", (0.0, 0.0, 0.0), "the head's true mounting off the nominal one (head "
                  "frame rotation vector): a bias the attitude fusion's alignment filter should find", "rad"),
    ParameterSpec("head.drift_amplitude_rad", (0.0, 0.0, 0.0), "thermo-elastic drift of the mounting: sinusoid "
                  "amplitude (head frame rotation vector)", "rad"),
    ParameterSpec("head.drift_period_s", 5700.0, "period of the thermo-elastic drift (about an orbit)", "s",
                  1.0, 1e9),
    *ENVIRONMENT_PARAMETERS,
    *EXCLUSION_PARAMETERS,
]


@dataclass(frozen=True)
class OrbitSetup:
    """The orbit parameters, checked: the model, its elements or lines, the head's mounting and misalignment."""

    model: str
    values: dict

    @property
    def enabled(self) -> bool:
        return self.model != "none"


def orbit_setup_from(values: dict) -> OrbitSetup:
    """Keep the orbit parameters (checked at configure: orbit_from, spacecraft_from)."""
    return OrbitSetup(values["orbit.model"], {spec.name: values[spec.name] for spec in ORBIT_PARAMETERS})


def epoch_unix_s(text: str, first_exposure_s: float) -> float:
    """Return orbit.epoch_utc as UNIX seconds (empty: the first exposure), ValueError naming the parameter."""
    if not text:
        return float(first_exposure_s)
    try:
        moment = datetime.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(f"orbit.epoch_utc={text!r} is not an ISO 8601 date and time (e.g. 2026-12-01T00:00:00)") \
            from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=datetime.timezone.utc)
    return moment.timestamp()


def orbit_from(setup: OrbitSetup, first_exposure_s: float):
    """Return the orbit (state(unix_s) -> r, v GCRS), None for "none" and "external"; ValueError on a bad element."""
    from ..models.orbit import KeplerianOrbit, OrbitElements, TleOrbit, sun_synchronous_inclination

    v = setup.values
    if setup.model == "tle":
        return TleOrbit(v["orbit.tle_line1"], v["orbit.tle_line2"])
    if setup.model != "kepler":
        return None
    altitude = v["orbit.altitude_m"]
    inclination = sun_synchronous_inclination(altitude, v["orbit.eccentricity"]) if v["orbit.sun_synchronous"] \
        else math.radians(v["orbit.inclination_deg"])
    elements = OrbitElements(6_378_137.0 + altitude, v["orbit.eccentricity"], inclination,
                             math.radians(v["orbit.raan_deg"]), math.radians(v["orbit.arg_perigee_deg"]),
                             math.radians(v["orbit.true_anomaly_deg"]),
                             epoch_unix_s(v["orbit.epoch_utc"], first_exposure_s))
    return KeplerianOrbit(elements)


def mounting_from(setup: OrbitSetup):
    """Return the head's nominal mounting and its misalignment (None when none), ValueError naming the parameter."""
    from ..sim.attitude_modes import HeadMounting
    from ..sim.spacecraft import Misalignment

    v = setup.values
    try:
        mounting = HeadMounting.from_quaternion(list(v["head.mounting_quaternion"]))
    except ValueError as exc:
        raise ValueError(f"head.mounting_quaternion={list(v['head.mounting_quaternion'])}: {exc}") from None
    offset, drift = v["head.misalignment_rad"], v["head.drift_amplitude_rad"]
    if not (np.any(offset) or np.any(drift)):
        return mounting, None
    try:
        return mounting, Misalignment(tuple(offset), tuple(drift), v["head.drift_period_s"])
    except ValueError as exc:
        raise ValueError(f"head.misalignment_rad / head.drift_amplitude_rad: {exc}") from None


def environment_model_from(setup: OrbitSetup) -> EnvironmentModel:
    """Return the EnvironmentModel of the environment.* parameters (with its exclusion angles)."""
    exclusion = ExclusionModel(**field_values(EXCLUSION_PARAMETERS, setup.values))
    return EnvironmentModel(**field_values(ENVIRONMENT_PARAMETERS, setup.values), exclusion=exclusion)
