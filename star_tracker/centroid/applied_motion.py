# SPDX-License-Identifier: Apache-2.0
"""The body motion a frame's spots were measured with: the centroider's smear aid, as applied."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .streak.exposure_path import PATH_FIT_RESIDUAL_FRACTION

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
    acceleration alpha. exposure_path_offset_rad: (3,) [rad] when the streaks were fitted on
    the path a gyro measured within the exposure (SmearModel.exposure_path), its
    mid_exposure_offset_rad (R_mid = R_mean exp([offset x])); the positions are then that path's
    exposure averages (angular_acceleration_rad_s2 None), with the path fit's residual
    (path_residual_covariance) beside the offset to mid-exposure. The tracker reads it to know
    what each attitude measured (track/rate.py, tracking.py); over ROS it travels on the
    centroider's `smear_aid/*` topics.
    """

    angular_velocity_rad_s: np.ndarray | None = None
    angular_acceleration_rad_s2: np.ndarray | None = None
    exposure_path_offset_rad: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("angular_velocity_rad_s", "angular_acceleration_rad_s2", "exposure_path_offset_rad"):
            value = getattr(self, name)
            if value is None:
                continue
            vector = np.array(value, dtype=float)
            if vector.shape != (3,) or not np.all(np.isfinite(vector)):
                raise ValueError(f"AppliedMotion.{name} must be 3 finite values or None, got {value!r}")
            object.__setattr__(self, name, vector)
        if self.exposure_path_offset_rad is not None and (self.angular_velocity_rad_s is None
                                                          or self.angular_acceleration_rad_s2 is not None):
            raise ValueError("AppliedMotion.exposure_path_offset_rad needs the rate the path was fitted with "
                             "and no angular acceleration")

    def path_residual_covariance(self) -> np.ndarray | None:
        """
        Attitude covariance [rad^2] (3, 3) of what a fit on a gyro's path leaves (None: not fitted on one).

        (PATH_FIT_RESIDUAL_FRACTION |offset|)^2 per axis (exposure_path.py): an error common to
        every star, not reduced by their number.
        """
        if self.exposure_path_offset_rad is None:
            return None
        sigma = PATH_FIT_RESIDUAL_FRACTION * float(np.linalg.norm(self.exposure_path_offset_rad))
        return np.eye(3) * sigma * sigma

    @staticmethod
    def of(smear: "SmearModel | None", rate_aid_rejected: bool, streaks_fitted: bool = False) -> "AppliedMotion":
        """
        Return what extract_spots applied of `smear` (None: nothing); a rejected aid leaves only its acceleration.

        streaks_fitted: spots were fitted on the smear's paths (FLAG_RATE_AIDED); only then does
        a gyro's path give the offset.
        """
        if smear is None:
            return NOT_AIDED
        alpha = smear.angular_acceleration_rad_s2
        if rate_aid_rejected:
            return AppliedMotion(None, alpha)
        path = smear.exposure_path if streaks_fitted else None
        return AppliedMotion(smear.angular_velocity_rad_s, alpha,
                             None if path is None else path.mid_exposure_offset_rad)


NOT_AIDED = AppliedMotion()
