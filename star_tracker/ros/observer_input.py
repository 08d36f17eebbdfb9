# SPDX-License-Identifier: Apache-2.0
"""
A node's observer input: the spacecraft's velocity (for the aberration) and position, per `observer.*`.

"none": nothing; "fixed": `observer.velocity_m_s` (the barycentric velocity, ICRS axes), no
position; "odometry": the spacecraft's geocentric GCRS position and velocity from `odometry`
(nav_msgs/Odometry, msg_docs/odometry.md) with the shipped ephemeris (the Earth's barycentric
velocity, the Sun and the Moon around it). A malformed, out-of-order or wrongly framed odometry
message is counted (`odometry_rejected`), logged and ignored; a frame whose odometry is older
than `observer.max_age_s` has no state (`frames_without_observer`). The identifier (in_orbit.py)
and the attitude fusion read it.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from nav_msgs.msg import Odometry

from ..models.observer_state import ObserverSample, ObserverSky, ObserverTrack
from . import convert
from .qos import TRUTH_INPUT_QOS, overridable

if TYPE_CHECKING:  # annotations only
    from .diagnostics import Diagnostics, Rejections

GCRS_FRAME = "gcrs"
MAX_SPEED_M_S = 3.0e5


class ObserverInput:
    """The observer input of one node (module docstring): configure() checks and subscribes, state_at() reads."""

    def __init__(self, node, values: dict, diag: "Diagnostics", reject: "Rejections"):
        self.node, self.values, self.diag, self.reject = node, values, diag, reject
        self.source = values["observer.source"]
        self.fixed_velocity: np.ndarray | None = None  # checked by configure
        self.track = self.sky = self.sub = None

    def configure(self) -> None:
        """Check observer.velocity_m_s (ValueError: the node stays unconfigured); with odometry, subscribe."""
        velocity = np.asarray(self.values["observer.velocity_m_s"], dtype=float)
        if velocity.shape != (3,) or not np.all(np.isfinite(velocity)) or np.linalg.norm(velocity) >= MAX_SPEED_M_S:
            raise ValueError(f"observer.velocity_m_s={list(self.values['observer.velocity_m_s'])} must be 3 finite "
                             "values below 300 km/s (the barycentric velocity, m/s)")
        self.fixed_velocity = velocity
        if self.source == "odometry":
            from ..models.ephemeris import load_ephemeris

            self.track = ObserverTrack(self.values["observer.max_age_s"])
            self.sky = ObserverSky(load_ephemeris())
            self.sub = self.node.create_subscription(Odometry, "odometry", self.on_odometry,
                                                     **overridable(TRUTH_INPUT_QOS))

    def release(self) -> None:
        if self.sub is not None:
            self.node.destroy_subscription(self.sub)
        self.track = self.sky = self.sub = None

    def on_odometry(self, msg: Odometry) -> None:
        """Executor thread: check and keep one observer sample (GCRS position [m] and velocity [m/s])."""
        if msg.header.frame_id != GCRS_FRAME or msg.child_frame_id not in (GCRS_FRAME, ""):
            self.reject("odometry_rejected", f"odometry in frame {msg.header.frame_id!r} -> {msg.child_frame_id!r}: "
                        f"expected {GCRS_FRAME!r} (position and velocity on GCRS axes); ignored")
            return
        p, v = msg.pose.pose.position, msg.twist.twist.linear
        try:
            self.track.add(convert.stamp_to_ns(msg.header.stamp), [p.x, p.y, p.z], [v.x, v.y, v.z])
        except ValueError as exc:
            self.reject("odometry_rejected", f"odometry rejected: {exc}")
            return
        self.diag.count("odometry_received")

    def state_at(self, stamp_ns: int) -> ObserverSample | None:
        """Return the spacecraft's state at a stamp (None: no odometry source, or none recent enough)."""
        if self.track is None:
            return None
        state = self.track.at(stamp_ns)
        if state is None:
            self.reject("frames_without_observer", f"no odometry within observer.max_age_s="
                        f"{self.values['observer.max_age_s']:g} s of {stamp_ns * 1e-9:.3f} s: the aberration is not "
                        "corrected (up to ~25\" off) and no cause is predicted")
        return state

    def velocity(self, state: ObserverSample | None) -> np.ndarray | None:
        """Return the observer's barycentric velocity [m/s] (ICRS axes) for the aberration (None: unknown)."""
        if self.source == "fixed":
            return self.fixed_velocity
        return None if state is None else self.sky.barycentric_velocity(state)
