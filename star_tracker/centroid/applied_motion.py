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
    acceleration alpha. exposure_path_offset_rad: (3,) [rad] when the frame was measured on
    the path a gyro measured within the exposure (SmearModel.exposure_path), its
    mid_exposure_offset_rad (R_mid = R_mean exp([offset x])): the positions are then that path's
    exposure averages (angular_acceleration_rad_s2 None), which the tracker carries to
    mid-exposure by this offset; exposure_path_offset_covariance: (3, 3) [rad^2] that offset's
    (ExposurePath.mid_exposure_offset_covariance), given with it. The tracker reads it to know
    what each attitude measured (track/rate.py, tracking.py); over ROS it travels on the
    centroider's `smear_aid/*` topics.
    """

    angular_velocity_rad_s: np.ndarray | None = None
    angular_acceleration_rad_s2: np.ndarray | None = None
    exposure_path_offset_rad: np.ndarray | None = None
    exposure_path_offset_covariance: np.ndarray | None = None

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
        covariance = self.exposure_path_offset_covariance
        if (covariance is None) != (self.exposure_path_offset_rad is None):
            raise ValueError("AppliedMotion.exposure_path_offset_rad and exposure_path_offset_covariance come together")
        if covariance is not None:
            matrix = np.array(covariance, dtype=float)
            if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)) or not np.allclose(matrix, matrix.T) \
                    or np.any(np.linalg.eigvalsh(0.5 * (matrix + matrix.T)) < 0):
                raise ValueError("AppliedMotion.exposure_path_offset_covariance must be a finite symmetric positive "
                                 f"semi-definite 3x3 [rad^2], got {covariance!r}")
            object.__setattr__(self, "exposure_path_offset_covariance", matrix)

    @staticmethod
    def of(smear: "SmearModel | None", rate_aid_rejected: bool) -> "AppliedMotion":
        """
        Return what extract_spots applied of `smear` (None: nothing); a rejected aid leaves only its acceleration.

        On a gyro's path (smear.exposure_path) every position is an exposure average, fitted on
        the path (a streak) or not (a point-like spot, smear under min_smear_px): the path's
        offset carries either to mid-exposure.
        """
        if smear is None:
            return NOT_AIDED
        alpha = smear.angular_acceleration_rad_s2
        if rate_aid_rejected:
            return AppliedMotion(None, alpha)
        path = smear.exposure_path
        if path is None:
            return AppliedMotion(smear.angular_velocity_rad_s, alpha)
        return AppliedMotion(smear.angular_velocity_rad_s, alpha, path.mid_exposure_offset_rad,
                             path.mid_exposure_offset_covariance)


NOT_AIDED = AppliedMotion()
