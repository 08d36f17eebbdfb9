# SPDX-License-Identifier: Apache-2.0
"""
The identifier in orbit: where the spacecraft is (observer input), the aberration correction, and the head's status.

Observer (`observer.*`, observer_input.py): "none" (no correction, no prediction: today's
behaviour), "fixed" (a barycentric velocity: the aberration corrected, no position so no
exclusion prediction), or "odometry" (the spacecraft's state with the ephemeris: the aberration
from the Earth's + the orbital velocity and the bodies' positions for the exclusion
prediction); a frame without a recent enough state gets neither correction nor prediction.

Status: one diagnostic_msgs/DiagnosticArray on `status` per frame the identifier finishes
(identified or not), stamped with the frame's stamp (msg_docs/status.md), from
track.head_status.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from ..centroid import Spots
from ..identify.aberration_correction import corrected_solution
from ..identify.base import Identification, direction_covariance
from ..models.camera import CameraModel
from ..models.observer_state import ObserverSample
from ..models.sky_geometry import ExclusionModel, head_geometry
from ..parameter_spec import field_values
from ..track.head_status import HeadFrameStatus, head_frame_status
from . import convert
from .identifier_parameters import EXCLUSION_PARAMETERS
from .observer_input import ObserverInput
from .qos import RESULT_QOS, overridable

if TYPE_CHECKING:  # annotations only
    from .diagnostics import Diagnostics, Rejections


class InOrbit:
    """The observer input, the aberration correction and the status topic of one identifier (module docstring)."""

    def __init__(self, node, values: dict, diag: "Diagnostics", reject: "Rejections"):
        self.node, self.values, self.diag = node, values, diag
        self.observer = ObserverInput(node, values, diag, reject)
        self.correct_aberration = values["observer.correct_aberration"]
        self.max_rate_rad_s = math.radians(values["status.max_rate_deg_s"])
        self.exclusion = self.pub = None  # checked and made by configure

    def configure(self) -> None:
        """Check the parameters (ValueError: the node stays unconfigured), subscribe, create the status publisher."""
        self.observer.configure()
        self.exclusion = ExclusionModel(**field_values(EXCLUSION_PARAMETERS, self.values))
        self.pub = self.node.create_lifecycle_publisher(DiagnosticArray, "status", **overridable(RESULT_QOS))

    def release(self) -> None:
        self.observer.release()
        if self.pub is not None:
            self.node.destroy_lifecycle_publisher(self.pub)
        self.pub = None

    def observer_at(self, stamp_ns: int) -> ObserverSample | None:
        """Return the spacecraft's state at a frame's stamp (None: no odometry source, or none recent enough)."""
        return self.observer.state_at(stamp_ns)

    def corrected(self, result: Identification, spots: Spots, camera: CameraModel, state: ObserverSample | None):
        """
        Return the attitude to publish: corrected for the observer's velocity when known and asked for.

        Refitted against the matched stars' apparent places with the identifier's own weights (the
        rays' covariances from the spots' pixel covariances through the camera model).
        """
        solution = result.attitude
        velocity = self.observer.velocity(state) if self.correct_aberration else None
        if velocity is None or not np.any(velocity):
            return solution
        self.diag.value("last_aberration_velocity_m_s", f"{np.linalg.norm(velocity):.1f}")
        index = result.spot_index
        ray_cov = direction_covariance(camera, spots.x[index], spots.y[index], spots.cov[index])
        return corrected_solution(solution, result.star_vectors, velocity, result.body_vectors, ray_cov)

    def status(self, stamp_ns: int, mode: str | None, state: ObserverSample | None, rotation: np.ndarray | None,
               rate: np.ndarray | None, half_fov_rad: float | None) -> HeadFrameStatus:
        """Return the frame's status: mode None = no attitude; rotation: the attitude or the last one propagated."""
        geometry = None
        if state is not None and rotation is not None and half_fov_rad is not None:
            geometry = head_geometry(rotation[:, 2], half_fov_rad, self.observer.sky.bodies(state), self.exclusion)
        return head_frame_status(mode, geometry, rate, self.max_rate_rad_s)

    def publish_status(self, stamp_ns: int, report: HeadFrameStatus, frame_id: str, stars: int,
                       on_exposure_path: bool = False) -> None:
        """
        Publish the frame's status on `status` and count it (status_<name> on /diagnostics).

        on_exposure_path: the attitude was carried to mid-exposure by a gyro's path within the
        exposure (the `exposure_path` key).
        """
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
                  "rate_rad_s": _number(report.rate_rad_s), "exposure_path": str(bool(on_exposure_path)).lower()}
        entry.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        self.pub.publish(DiagnosticArray(header=Header(stamp=convert.ns_to_stamp(stamp_ns), frame_id=frame_id),
                                         status=[entry]))


def _number(value: float) -> str:
    """Format a float for a KeyValue: 6 significant digits, "" when unknown (nan)."""
    return "" if math.isnan(value) else f"{value:.6g}"
