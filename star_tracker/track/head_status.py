# SPDX-License-Identifier: Apache-2.0
"""
A head's status for one frame: what it did, and when it gave no attitude, why.

Flight units report why a head has no solution (blinded by the Sun, the Earth or the Moon,
occulted by the Earth, rate too high); so does the identifier, per frame, from what it did
(a tracked or lost-in-space attitude, or none) and, when it gave none, from the bright
bodies' geometry predicted from the ephemeris, the spacecraft's position and the head's last
attitude (models.sky_geometry), then from its rate estimate.

Statuses, with their diagnostic level:
- `tracking` (OK): an attitude from tracking;
- `lost_in_space` (OK with an attitude: a lost-in-space solve; WARN without: searching, no
  known cause);
- `occulted`, `blinded_sun`, `blinded_earth`, `blinded_moon` (ERROR): no attitude, and the
  geometry says why (the boresight behind the Earth, or a body inside its exclusion angle);
- `rate_too_high` (ERROR): no attitude, and the last rate estimate exceeds the head's
  tracking limit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..models.sky_geometry import HeadGeometry, HeadStatus

TRACKING, LOST_IN_SPACE, RATE_TOO_HIGH = "tracking", "lost_in_space", "rate_too_high"
OCCULTED, BLINDED_SUN, BLINDED_EARTH, BLINDED_MOON = (HeadStatus.OCCULTED.value, HeadStatus.BLINDED_SUN.value,
                                                      HeadStatus.BLINDED_EARTH.value, HeadStatus.BLINDED_MOON.value)
STATUSES = (TRACKING, LOST_IN_SPACE, OCCULTED, BLINDED_SUN, BLINDED_EARTH, BLINDED_MOON, RATE_TOO_HIGH)
OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels


@dataclass(frozen=True)
class HeadFrameStatus:
    """
    One frame's status (see the module docstring).

    status: one of STATUSES; level: OK, WARN or ERROR; attitude: an attitude was published;
    predicted: the geometry's verdict (sky_geometry.HeadStatus value; "unknown" without a
    spacecraft position or a head attitude); sun_angle_rad, moon_angle_rad,
    earth_limb_angle_rad: from the boresight [rad] (nan when unknown); rate_rad_s: the norm of
    the last rate estimate [rad/s] (nan when none).
    """

    status: str
    level: int
    attitude: bool
    predicted: str = "unknown"
    sun_angle_rad: float = math.nan
    moon_angle_rad: float = math.nan
    earth_limb_angle_rad: float = math.nan
    rate_rad_s: float = math.nan


def head_frame_status(mode: str | None, geometry: HeadGeometry | None, rate_rad_s: np.ndarray | None,
                      max_rate_rad_s: float) -> HeadFrameStatus:
    """
    Return a frame's status.

    mode: "tracking" or "lost_in_space" when an attitude was published (track.tracking's
    TrackedFrame.mode), None when not; geometry: the predicted head geometry at the frame's
    stamp (None: unknown); rate_rad_s: the last body-rate estimate (3,) [rad/s] (None: none);
    max_rate_rad_s: the head's tracking limit [rad/s].
    """
    angles = {}
    predicted = "unknown"
    if geometry is not None:
        predicted = geometry.status.value
        angles = dict(sun_angle_rad=float(geometry.sun_angle_rad), moon_angle_rad=float(geometry.moon_angle_rad),
                      earth_limb_angle_rad=float(geometry.earth_limb_angle_rad))
    rate = float(np.linalg.norm(rate_rad_s)) if rate_rad_s is not None else math.nan
    common = dict(predicted=predicted, rate_rad_s=rate, **angles)
    if mode is not None:
        status = TRACKING if mode == TRACKING else LOST_IN_SPACE
        return HeadFrameStatus(status, OK, True, **common)
    if predicted in (OCCULTED, BLINDED_SUN, BLINDED_EARTH, BLINDED_MOON):
        return HeadFrameStatus(predicted, ERROR, False, **common)
    if rate > max_rate_rad_s:
        return HeadFrameStatus(RATE_TOO_HIGH, ERROR, False, **common)
    return HeadFrameStatus(LOST_IN_SPACE, WARN, False, **common)
