# SPDX-License-Identifier: Apache-2.0
"""The body motion a frame's spots were measured with: the centroider's smear aid, as applied."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..models.attitude import rotation_vector_to_matrix
from ..models.matrix_checks import covariance_problem

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
            problem = covariance_problem(covariance, definite=False)
            if problem is not None:
                raise ValueError(f"AppliedMotion.exposure_path_offset_covariance [rad^2] is {problem}")
            object.__setattr__(self, "exposure_path_offset_covariance", np.array(covariance, dtype=float))

    def at_mid_exposure(self, rotation: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        Return an exposure-average attitude on the gyro's path carried to mid-exposure, with its covariance.

        rotation: (3, 3) sensor -> ICRS measured from this frame's spots; covariance: (3, 3)
        [rad^2, sensor frame]. R_mid = R exp([exposure_path_offset_rad x]); the offset's
        covariance added. Only for a frame measured on a path (exposure_path_offset_rad set).
        """
        if self.exposure_path_offset_rad is None:
            raise ValueError("AppliedMotion.at_mid_exposure: the frame was not measured on a gyro's path")
        return (np.asarray(rotation, float) @ rotation_vector_to_matrix(self.exposure_path_offset_rad),
                np.asarray(covariance, float) + self.exposure_path_offset_covariance)

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
