# SPDX-License-Identifier: Apache-2.0
"""
The identifier in orbit: where the spacecraft is (observer input), the aberration correction, and the head's status.

Observer (parameter `observer.source`): "none" (no correction, no prediction: today's
behaviour), "fixed" (`observer.velocity_m_s`, the barycentric velocity on ICRS axes: the
aberration corrected, no position so no exclusion prediction), or "odometry" (the spacecraft's
geocentric GCRS position and velocity from `odometry`, nav_msgs/Odometry, msg_docs/odometry.md:
with the ephemeris, the aberration from the Earth's + the orbital velocity and the bodies'
positions for the exclusion prediction). A malformed, out-of-order or wrongly framed odometry
message is counted (`odometry_rejected`), logged and ignored; a frame whose odometry is older
than `observer.max_age_s` gets neither correction nor prediction (`frames_without_observer`).

Status: one diagnostic_msgs/DiagnosticArray on `status` per frame the identifier finishes
(identified or not), stamped with the frame's stamp (msg_docs/status.md), from
track.head_status.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
from std_msgs.msg import Header

from ..identify.aberration_correction import corrected_solution
from ..models.observer_state import ObserverSample, ObserverSky, ObserverTrack
from ..models.sky_geometry import ExclusionModel, head_geometry
from ..parameter_spec import field_values
from ..track.head_status import HeadFrameStatus, head_frame_status
from . import convert
from .identifier_parameters import EXCLUSION_PARAMETERS
from .qos import RESULT_QOS, TRUTH_INPUT_QOS, overridable

if TYPE_CHECKING:  # annotations only
    from .diagnostics import Diagnostics, Rejections

GCRS_FRAME = "gcrs"


class InOrbit:
    """The observer input, the aberration correction and the status topic of one identifier (module docstring)."""

    def __init__(self, node, values: dict, diag: "Diagnostics", reject: "Rejections"):
        self.node, self.values, self.diag, self.reject = node, values, diag, reject
        self.source = values["observer.source"]
        self.correct_aberration = values["observer.correct_aberration"]
        self.max_rate_rad_s = math.radians(values["status.max_rate_deg_s"])
        self.fixed_velocity = self.exclusion = None  # checked by configure
        self.track = self.sky = self.sub = self.pub = None

    def configure(self) -> None:
        """
        Check the parameters (ValueError: the node stays unconfigured), create the status publisher.

        With observer.source odometry also load the ephemeris and subscribe to odometry.
        """
        velocity = np.asarray(self.values["observer.velocity_m_s"], dtype=float)
        if velocity.shape != (3,) or not np.all(np.isfinite(velocity)) or np.linalg.norm(velocity) >= 3.0e5:
            raise ValueError(f"observer.velocity_m_s={list(self.values['observer.velocity_m_s'])} must be 3 finite "
                             "values below 300 km/s (the barycentric velocity, m/s)")
        self.fixed_velocity = velocity
        self.exclusion = ExclusionModel(**field_values(EXCLUSION_PARAMETERS, self.values))
        self.pub = self.node.create_lifecycle_publisher(DiagnosticArray, "status", **overridable(RESULT_QOS))
        if self.source == "odometry":
            from ..models.ephemeris import load_ephemeris

            self.track = ObserverTrack(self.values["observer.max_age_s"])
            self.sky = ObserverSky(load_ephemeris())
            self.sub = self.node.create_subscription(Odometry, "odometry", self.on_odometry,
                                                     **overridable(TRUTH_INPUT_QOS))

    def release(self) -> None:
        if self.sub is not None:
            self.node.destroy_subscription(self.sub)
        if self.pub is not None:
            self.node.destroy_lifecycle_publisher(self.pub)
        self.track = self.sky = self.sub = self.pub = None

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

    def observer_at(self, stamp_ns: int) -> ObserverSample | None:
        """Return the spacecraft's state at a frame's stamp (None: no odometry source, or none recent enough)."""
        if self.track is None:
            return None
        state = self.track.at(stamp_ns)
        if state is None:
            self.diag.count("frames_without_observer")
        return state

    def velocity_at(self, state: ObserverSample | None) -> np.ndarray | None:
        """Return the observer's barycentric velocity [m/s] for the aberration (None: unknown)."""
        if self.source == "fixed":
            return self.fixed_velocity
        return None if state is None else self.sky.barycentric_velocity(state)

    def corrected(self, solution, star_vectors: np.ndarray, state: ObserverSample | None):
        """Return the attitude to publish: corrected for the observer's velocity when known and asked for."""
        velocity = self.velocity_at(state) if self.correct_aberration else None
        if velocity is None or not np.any(velocity):
            return solution
        self.diag.value("last_aberration_velocity_m_s", f"{np.linalg.norm(velocity):.1f}")
        return corrected_solution(solution, star_vectors, velocity)

    def status(self, stamp_ns: int, mode: str | None, state: ObserverSample | None, rotation: np.ndarray | None,
               rate: np.ndarray | None, half_fov_rad: float | None) -> HeadFrameStatus:
        """Return the frame's status: mode None = no attitude; rotation: the attitude or the last one propagated."""
        geometry = None
        if state is not None and rotation is not None and half_fov_rad is not None:
            geometry = head_geometry(rotation[:, 2], half_fov_rad, self.sky.bodies(state), self.exclusion)
        return head_frame_status(mode, geometry, rate, self.max_rate_rad_s)

    def publish_status(self, stamp_ns: int, report: HeadFrameStatus, frame_id: str, stars: int) -> None:
        """Publish the frame's status on `status` and count it (status_<name> on /diagnostics)."""
        self.diag.count(f"status_{report.status}")
        self.diag.value("status", report.status)
        if self.pub is None:
            return
        entry = DiagnosticStatus(level=bytes([report.level]), name=self.diag.name, message=report.status,
                                 hardware_id=frame_id)
        values = {"attitude": str(report.attitude).lower(), "stars_matched": str(stars),
                  "predicted": report.predicted, "sun_angle_rad": _number(report.sun_angle_rad),
                  "moon_angle_rad": _number(report.moon_angle_rad),
                  "earth_limb_angle_rad": _number(report.earth_limb_angle_rad),
                  "rate_rad_s": _number(report.rate_rad_s)}
        entry.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        self.pub.publish(DiagnosticArray(header=Header(stamp=convert.ns_to_stamp(stamp_ns), frame_id=frame_id),
                                         status=[entry]))


def _number(value: float) -> str:
    """Format a float for a KeyValue: 6 significant digits, "" when unknown (nan)."""
    return "" if math.isnan(value) else f"{value:.6g}"
