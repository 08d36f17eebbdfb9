# SPDX-License-Identifier: Apache-2.0
"""
The camera_simulator's world: the orbit, the body's motion, the head's mounting, each frame's environment.

Built from the orbit parameters (camera_simulator_orbit.py), checked at configure (a bad orbit,
TLE or mounting raises ValueError: the node stays unconfigured), the body's motion made at the
first exposure (an empty orbit.epoch_utc is that exposure). Without an orbit (orbit.model
"none") and with the default mounting, the head's motion is the attitude profile's and no
frame has an environment: today's frames, unchanged.
"""
from __future__ import annotations

import time

import numpy as np
from nav_msgs.msg import Odometry

from ..models.observer_state import ObserverTrack
from ..sim.environment import EnvironmentModel
from ..sim.motion import motion_from_parameters
from . import convert
from .camera_simulator_orbit import (ORBIT_PROFILES, OrbitSetup, environment_model_from, mounting_from, orbit_from)

GCRS_FRAME = "gcrs"
EXTERNAL_STATE_MAX_AGE_S = 10.0  # truth_in/odometry older than this at a frame: no environment (counted)


class CameraWorld:
    """One camera's world (module docstring); `orbiting`: an orbit is set; `external_orbit`: from truth_in/odometry."""

    def __init__(self, setup: OrbitSetup, profile: str):
        self.setup, self.profile = setup, profile
        self.orbiting = setup.enabled
        self.external_orbit = setup.model == "external"
        self.environment_model = EnvironmentModel()
        self.orbit = self.ephemeris = self.mounting = self.misalignment = self.spacecraft = self.states = None

    def configure(self, now_s: float | None) -> None:
        """
        Check everything the first exposure will need (ValueError naming the parameter) and load the ephemeris.

        now_s: the node's clock [s, UNIX]; None while a sim clock has not ticked (the orbit and the
        ephemeris are then checked against the time only at the first exposure).
        """
        if self.profile in ORBIT_PROFILES and self.setup.model not in ("kepler", "tle"):
            raise ValueError(f"attitude.profile={self.profile!r} needs an orbit: orbit.model kepler or tle "
                             f"(is {self.setup.model!r})")
        self.mounting, self.misalignment = mounting_from(self.setup)
        if not self.orbiting:
            return
        self.environment_model = environment_model_from(self.setup)
        self.orbit = orbit_from(self.setup, now_s if now_s is not None else time.time())  # the elements checked
        from ..models.ephemeris import load_ephemeris

        self.ephemeris = load_ephemeris()
        if now_s is not None:
            if self.orbit is not None:
                self.orbit.state(now_s)  # a TLE SGP4 cannot propagate to now fails here, not at the first frame
            self.ephemeris.sun_position(now_s)  # a clock outside the ephemeris' span fails here, naming the span
        if self.external_orbit:
            self.states = ObserverTrack(EXTERNAL_STATE_MAX_AGE_S)

    def release(self) -> None:
        self.orbit = self.spacecraft = self.states = None

    def describe(self) -> str:
        """Return a log line's tail: the orbit and the mounting, or "" without either."""
        parts = []
        if self.orbiting:
            parts.append(f"orbit {self.setup.model}")
        if self.mounting is not None and not np.allclose(self.mounting.head_to_body, np.eye(3)):
            parts.append(f"head mounting q={np.round(self.mounting.quaternion, 6).tolist()}")
        if self.misalignment is not None:
            parts.append("misaligned")
        return "".join(f", {p}" for p in parts)

    def body_motion(self, profile: str, initial_rotation: np.ndarray, t0_s: float, motion_kwargs: dict):
        """Return the body's motion from the first exposure t0_s [s] (the orbit's epoch if orbit.epoch_utc is empty)."""
        if self.orbiting and not self.external_orbit:
            self.orbit = orbit_from(self.setup, t0_s)
        if profile == "nadir":
            from ..sim.attitude_modes import NadirPointingMotion

            return NadirPointingMotion(self.orbit)
        if profile == "sun_pointing":
            from ..sim.attitude_modes import SunPointingMotion

            return SunPointingMotion(self.orbit, self.ephemeris)
        return motion_from_parameters(profile, initial_rotation, t0=t0_s, **motion_kwargs[profile])

    def head_motion(self, body_motion):
        """Return the head's true motion on the body (the body's own with the default mounting and no misalignment)."""
        if body_motion is None:
            raise ValueError("no external truth received yet")
        if self.misalignment is None and np.allclose(self.mounting.head_to_body, np.eye(3), rtol=0.0, atol=0.0):
            return body_motion
        from ..sim.attitude_modes import MountedHeadMotion
        from ..sim.spacecraft import MisalignedHeadMotion

        motion = MountedHeadMotion(body_motion, self.mounting)
        return motion if self.misalignment is None else MisalignedHeadMotion(motion, self.misalignment)

    def environment(self, stamp_ns: int):
        """Return the frame's Environment and the spacecraft's (position, velocity), both None without an orbit."""
        if not self.orbiting:
            return None, None
        from ..sim.spacecraft import environment_at

        unix_s = stamp_ns * 1e-9
        if self.external_orbit:
            state = self.states.at(stamp_ns)
            if state is None:
                raise ValueError("no recent truth_in/odometry for this exposure")
            r, v = state.position_m, state.velocity_m_s
        else:
            r, v = (np.asarray(x, float) for x in self.orbit.state(unix_s))
        return environment_at(self.ephemeris, unix_s, r, v), (r, v)

    def add_state(self, msg: Odometry) -> None:
        """Keep one external state (truth_in/odometry: GCRS position [m] and velocity [m/s]); ValueError if bad."""
        if msg.header.frame_id != GCRS_FRAME or msg.child_frame_id not in (GCRS_FRAME, ""):
            raise ValueError(f"frame {msg.header.frame_id!r} -> {msg.child_frame_id!r}: expected {GCRS_FRAME!r}")
        p, v = msg.pose.pose.position, msg.twist.twist.linear
        self.states.add(convert.stamp_to_ns(msg.header.stamp), [p.x, p.y, p.z], [v.x, v.y, v.z])
