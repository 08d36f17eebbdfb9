# SPDX-License-Identifier: Apache-2.0
"""
Online refinement of the focal length and k1 from the stars a tracker identifies (thermo-elastic drift).

`OnlineCalibration` keeps the matched stars of the newest `max_frames` solved frames, re-fits
f and k1 (models/camera_calibration.py, principal point and k2 left as given) every
`frames_per_fit` frames, and offers the estimate for identification only when it is
trustworthy: a parameter is applied when its 1-sigma effect at the image corner is at most
`apply_corner_sigma_px` (default 0.3 px, well inside the identifier's 1.5 px match radius),
the others stay at the nominal camera's values. ROS-free: the identifier node feeds it.
Units: pixels [px]; k1 dimensionless.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from ..parameter_spec import parameter, range_problems
from .camera import CameraModel
from .camera_calibration import CalibrationConfig, CalibrationFrame, CameraCalibration, calibrate_camera


@dataclass(frozen=True)
class OnlineCalibrationConfig:
    """
    Parameters of the online calibration.

    frames_per_fit: solved frames between fits; max_frames: newest frames kept for a fit;
    min_stars: fewest matched stars a frame needs to be kept; apply_corner_sigma_px: the rule
    above [px]; sigma_floor_px: added in quadrature to each spot's 1-sigma [px].
    """

    frames_per_fit: int = parameter(10, "solved frames between two fits", "", 1, 100000)
    max_frames: int = parameter(20, "newest solved frames (>= min_stars stars) a fit uses", "", 1, 1000)
    min_stars: int = 5
    apply_corner_sigma_px: float = parameter(0.3, "a fitted f or k1 is applied when its 1-sigma moves the image "
                                             "corner by at most this", "px", 0.0, 10.0, low_open=True)
    sigma_floor_px: float = 0.05

    def __post_init__(self) -> None:
        problems = range_problems(self)
        if self.min_stars < 3:
            problems.append(f"min_stars={self.min_stars} must be >= 3")
        if not (np.isfinite(self.sigma_floor_px) and self.sigma_floor_px >= 0):
            problems.append(f"sigma_floor_px={self.sigma_floor_px} must be >= 0")
        if problems:
            raise ValueError("invalid online calibration config: " + "; ".join(problems))


class OnlineCalibration:
    """Accumulate (add), re-fit periodically, and apply (camera_for) the f, k1 estimate."""

    def __init__(self, config: OnlineCalibrationConfig = OnlineCalibrationConfig()):
        self.config = config
        self.frames: deque = deque(maxlen=config.max_frames)
        self.nominal: CameraModel | None = None
        self._current: tuple = (None, (), None)  # (estimate, applied parameter names, refined camera)
        self.fits = 0
        self._since_fit = 0

    def reset(self, nominal: CameraModel) -> None:
        """Take a new nominal camera (another camera_info): forget the frames and the estimate."""
        self.nominal, self._current = nominal, (None, (), None)
        self.frames.clear()
        self._since_fit = 0

    def add(self, spots, identification, camera: CameraModel) -> CameraCalibration | None:
        """
        One solved frame (its spots, Identification and the nominal camera).

        Kept when it has min_stars; returns the new estimate when this frame completes a fit,
        else None.
        """
        if camera != self.nominal:
            self.reset(camera)
        if not identification.solved or identification.hip.size < self.config.min_stars:
            return None
        self.frames.append(CalibrationFrame.from_identification(spots, identification))
        self._since_fit += 1
        if self._since_fit < self.config.frames_per_fit:
            return None
        self._since_fit = 0
        estimate = calibrate_camera(list(self.frames), self.nominal,
                                    CalibrationConfig(fit=("f", "k1"), sigma_floor_px=self.config.sigma_floor_px))
        self.fits += 1
        applied = tuple(n for n in estimate.fitted if estimate.corner_sigma_px[n] <= self.config.apply_corner_sigma_px)
        self._current = (estimate, applied, self._refined(estimate, applied))  # one assignment: camera_for's thread
        return estimate

    def _refined(self, estimate: CameraCalibration, applied: tuple[str, ...]) -> CameraModel:
        """Return the nominal camera with the applied parameters of `estimate` (f scales fx and fy alike)."""
        camera, fitted = self.nominal, estimate.camera
        scale = fitted.fx / camera.fx if "f" in applied else 1.0
        k1 = fitted.distortion[0] if "k1" in applied else camera.distortion[0]
        return CameraModel(camera.width, camera.height, camera.fx * scale, camera.fy * scale, camera.cx, camera.cy,
                           (k1, *camera.distortion[1:]))

    @property
    def estimate(self) -> CameraCalibration | None:
        """The latest fit (None before the first)."""
        return self._current[0]

    @property
    def applied(self) -> tuple[str, ...]:
        """The parameters of the latest fit that camera_for applies ("f", "k1")."""
        return self._current[1]

    def camera_for(self, camera: CameraModel) -> CameraModel:
        """
        Return the camera to identify with.

        `camera` with the applied parameters of the estimate (f scales fx and fy alike; k1),
        or `camera` itself when none applies or it is not the nominal camera the estimate
        refers to. Safe to call from another thread than add().
        """
        _, applied, refined = self._current
        return refined if applied and camera == self.nominal else camera
