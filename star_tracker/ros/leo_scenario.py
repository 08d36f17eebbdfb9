# SPDX-License-Identifier: Apache-2.0
"""
The LEO scenario's node parameters: N heads on a nadir-pointing spacecraft and their fusion (ROS-free).

A 550 km sun-synchronous circular orbit (orbit.* defaults, one epoch for every head: their
cameras expose on their own schedules, and each body attitude is the orbit's at that instant),
the body nadir-pointing (LVLH), and heads on the zenith side: two by default, 45 deg off
zenith toward the body's -Y and +Y (90 deg apart; a sun-synchronous orbit's Sun lies near the
orbit normal, so it comes near one head at a time), a third along zenith. Each identifier
reads its camera's truth/odometry (aberration corrected, exclusions predicted); its tracker is
told the body turns slowly and smoothly (the orbital rate, ~0.06 deg/s) so that frames seconds
apart in a fast scenario are tracked: a rate window and a coast of 10 s, an acceleration bound of
1e-4 rad/s^2. The fusion takes the body rate from the heads and models the heads' thermo-elastic
drift as periodic over the orbit (alignment.harmonic_period_s). `launch/multi_head.launch.py
scenario:=leo` and `star-tracker demo --scenario leo --heads N` use it.
"""
from __future__ import annotations

import math

import numpy as np

from ..models.attitude import matrix_to_quaternion, rotation_vector_to_matrix

ZENITH_TILT_DEG = 45.0  # the heads' boresights from zenith (body -Z on a nadir-pointing body)


def _mounting(axis_angle_deg: tuple[float, float, float]) -> tuple[float, ...]:
    """Return the head frame's orientation in the body frame (x, y, z, w) for a rotation vector [deg]."""
    return tuple(float(v) for v in matrix_to_quaternion(rotation_vector_to_matrix(np.radians(axis_angle_deg))))


# Head sensor frame in the body frame: +Z (boresight) from body +Z (nadir) turned 180 -/+ 45 deg about
# body X, i.e. 45 deg off zenith toward body -Y / +Y; head3 at zenith.
LEO_MOUNTINGS = {"head1": _mounting((180.0 - ZENITH_TILT_DEG, 0.0, 0.0)),
                 "head2": _mounting((-(180.0 - ZENITH_TILT_DEG), 0.0, 0.0)),
                 "head3": _mounting((180.0, 0.0, 0.0))}
# The simulator in orbit renders blooming (sim.blooming): the centroider leaves the spill out of its fits.
CENTROIDER = {"sensor_blooms": True}
IDENTIFIER = {"observer.source": "odometry", "tracking.max_coast_s": 10.0, "tracking.rate_window_s": 10.0,
              "tracking.max_angular_acceleration_rad_s2": 1e-4}
# The navigation input: each identifier reads its own camera's truth/odometry; the fusion head1's
# (every camera flies the same orbit).
REMAPS = {"identifier": {"odometry": "truth/odometry"}, "attitude_fusion": {"odometry": "head1/truth/odometry"}}


def head_names(count: int) -> list[str]:
    if not 1 <= count <= len(LEO_MOUNTINGS):
        raise ValueError(f"{count} heads: the LEO scenario has mountings for 1 to {len(LEO_MOUNTINGS)}")
    return [f"head{i}" for i in range(1, count + 1)]


def camera_parameters(head: str, index: int, rate_hz: float, epoch_utc: str) -> dict:
    """Return one head's camera_simulator parameters: the orbit (epoch_utc: ISO 8601), body, mounting, noise, sync."""
    return {"orbit.model": "kepler", "orbit.epoch_utc": epoch_utc, "attitude.profile": "nadir",
            "head.mounting_quaternion": list(LEO_MOUNTINGS[head]), "rate_hz": float(rate_hz),
            "frame_id": f"{head}_optical", "seed": index, "fixed_pattern_seed": index,
            "sync_exposures": True}  # every head exposes at the same stamps, as on one sync pulse


def epoch_utc(unix_s: float) -> str:
    """Return unix_s [s] as an ISO 8601 UTC string (orbit.epoch_utc)."""
    import datetime

    return datetime.datetime.fromtimestamp(unix_s, tz=datetime.timezone.utc).isoformat()


def orbital_period_s() -> float:
    """Return the period [s] of the camera_simulator's default orbit (orbit.altitude_m, J2 included)."""
    from ..models.orbit import KeplerianOrbit, OrbitElements, sun_synchronous_inclination
    from .camera_simulator_orbit import ORBIT_PARAMETERS

    altitude = next(spec.default for spec in ORBIT_PARAMETERS if spec.name == "orbit.altitude_m")
    return KeplerianOrbit(OrbitElements.circular(altitude, sun_synchronous_inclination(altitude), 0.0, 0.0,
                                                 0.0)).period_s


def fusion_parameters(heads: list[str]) -> dict:
    """Return the attitude_fusion parameters: the heads, their mountings, the body rate from the heads, the orbit."""
    return {"heads": list(heads), **{f"mounting.{h}": list(LEO_MOUNTINGS[h]) for h in heads},
            "body_rate.source": "heads", "body_rate.max_age_s": 10.0,
            "alignment.harmonic_period_s": orbital_period_s(), "alignment.drift_psd_rad2_s": 2.4e-16,
            "fusion.stale_after_s": 1.0,  # synchronised heads: a head that missed the stamp is left out, not propagated
            "observer.source": "odometry",
            "fusion.max_wait_s": 2.0}  # on a 30x sim clock a head's solution comes ~1-3 s of its time after the other's


def boresight_from_zenith_deg(head: str) -> float:
    """Return the angle [deg] of a head's boresight from zenith (body -Z) on the nadir-pointing body."""
    from ..models.attitude import quaternion_to_matrix

    boresight = quaternion_to_matrix(np.asarray(LEO_MOUNTINGS[head])) @ np.array([0.0, 0.0, 1.0])
    return math.degrees(math.acos(float(np.clip(-boresight[2], -1.0, 1.0))))
