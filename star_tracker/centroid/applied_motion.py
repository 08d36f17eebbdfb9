# SPDX-License-Identifier: Apache-2.0
"""The body motion a frame's spots were measured with: the centroider's smear aid, as applied."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .streak.smear import SmearModel


@dataclass(frozen=True)
class AppliedMotion:
    """
    The rate and acceleration a frame's spots were measured with, in the sensor frame.

    angular_velocity_rad_s: (3,) [rad/s] the streaks were fitted on (their predicted paths),
    None when no rate aid was applied (no aid, or the image disagreed with it): point-like and
    free streak fits. angular_acceleration_rad_s2: (3,) [rad/s^2] the positions were corrected
    by to mid-exposure (extract.to_mid_exposure, the accelerated paths), None when none was:
    the positions are the exposure averages, off mid-exposure by alpha T^2 / 24 under an
    acceleration alpha. The tracker reads it to know what each attitude measured
    (track/rate.py); over ROS it travels on the centroider's `smear_aid/*` topics.
    """

    angular_velocity_rad_s: np.ndarray | None = None
    angular_acceleration_rad_s2: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("angular_velocity_rad_s", "angular_acceleration_rad_s2"):
            value = getattr(self, name)
            if value is None:
                continue
            vector = np.array(value, dtype=float)
            if vector.shape != (3,) or not np.all(np.isfinite(vector)):
                raise ValueError(f"AppliedMotion.{name} must be 3 finite values or None, got {value!r}")
            object.__setattr__(self, name, vector)

    @staticmethod
    def of(smear: "SmearModel | None", rate_aid_rejected: bool) -> "AppliedMotion":
        """Return what extract_spots applied of `smear` (None: nothing); a rejected aid leaves only its acceleration."""
        if smear is None:
            return NOT_AIDED
        alpha = smear.angular_acceleration_rad_s2
        return AppliedMotion(None if rate_aid_rejected else smear.angular_velocity_rad_s, alpha)


NOT_AIDED = AppliedMotion()
