# SPDX-License-Identifier: Apache-2.0
"""
Camera geometry: pinhole intrinsics + Brown-Conrady distortion, OpenCV conventions.

Sensor frame `star_tracker_optical`: +Z boresight, +X image right (columns), +Y image down
(rows). Pixel (0, 0) is the centre of the top-left pixel. Distortion coefficients are
OpenCV / ROS `plumb_bob` order (k1, k2, p1, p2, k3), so `CameraInfo` K and D describe
the model exactly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np


@dataclass(frozen=True)
class CameraModel:
    """width, height [px]; fx, fy, cx, cy [px]; distortion (k1, k2, p1, p2, k3) [-]."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    _k: np.ndarray = field(init=False, repr=False, compare=False)
    _d: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        problems = []
        if not (int(self.width) > 0 and int(self.height) > 0):
            problems.append(f"image size {self.width}x{self.height} must be positive")
        for name in ("fx", "fy", "cx", "cy"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                problems.append(f"{name}={value} is not finite")
        if np.isfinite(self.fx) and np.isfinite(self.fy) and (self.fx <= 0 or self.fy <= 0):
            problems.append(f"focal lengths fx={self.fx}, fy={self.fy} must be > 0")
        if len(self.distortion) != 5 or not np.all(np.isfinite(self.distortion)):
            problems.append(f"distortion {self.distortion} must be 5 finite plumb_bob coefficients")
        if problems:
            raise ValueError("invalid camera model: " + "; ".join(problems))
        object.__setattr__(self, "_k", self.intrinsic_matrix())
        object.__setattr__(self, "_d", np.asarray(self.distortion, dtype=float))

    @staticmethod
    def from_fov(width: int, height: int, fov_x_rad: float,
                 distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)) -> "CameraModel":
        """Square pixels, principal point at the image centre, horizontal FOV [rad]."""
        f = 0.5 * width / np.tan(0.5 * fov_x_rad)
        return CameraModel(int(width), int(height), f, f, (width - 1) / 2.0, (height - 1) / 2.0,
                           tuple(float(d) for d in distortion))

    def intrinsic_matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(d != 0.0 for d in self.distortion)  # plain floats: asked on every frame

    @property
    def pixel_scale_rad(self) -> float:
        """Angle subtended by one pixel at the principal point [rad/px]."""
        return 1.0 / math.sqrt(self.fx * self.fy)

    @cached_property  # the model is immutable; asked by every verification
    def half_diagonal_fov_rad(self) -> float:
        """Angle from the boresight to the farthest image corner [rad]."""
        if not self.has_distortion:  # a pinhole: plain floats (cameras are made per field hypothesis)
            return max(math.atan(math.hypot((u - self.cx) / self.fx, (v - self.cy) / self.fy))
                       for u in (0.0, self.width - 1.0) for v in (0.0, self.height - 1.0))
        corners = np.array([[0, 0], [self.width - 1, 0], [0, self.height - 1],
                            [self.width - 1, self.height - 1]], dtype=float)
        rays = self.pixel_to_ray(corners[:, 0], corners[:, 1])
        return float(np.max(np.arccos(np.clip(rays[:, 2], -1.0, 1.0))))

    @cached_property
    def max_imaged_radius2(self) -> float:
        """
        Squared normalized radius (x^2 + y^2, x = X/Z) beyond which the radial distortion stops growing [-].

        Where d(r (1 + k1 r^2 + k2 r^4 + k3 r^6))/dr first falls to 0 (inf when it never
        does): beyond it the polynomial folds directions far off-axis back into the image, a
        place no lens images them (two directions would share a pixel).
        """
        k1, k2, _, _, k3 = (float(d) for d in self.distortion)
        # 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3 = 0, s = r^2; with t = 1/s the monic t^3 + 3 k1 t^2 +
        # 5 k2 t + 7 k3 = 0 (no division by a tiny k3): s = 1 / the largest positive real t.
        # Plain floats without k3: calibration makes a camera per evaluation.
        with np.errstate(all="ignore"):
            if k3 != 0.0:
                try:
                    roots = np.roots([1.0, 3.0 * k1, 5.0 * k2, 7.0 * k3])
                except np.linalg.LinAlgError:  # coefficients overflowing to inf
                    return math.inf
                ts = [r.real for r in roots if abs(r.imag) <= 1e-7 * abs(r)]
            else:  # t (t^2 + 3 k1 t + 5 k2) = 0
                discriminant = 9.0 * k1 * k1 - 20.0 * k2
                root = math.sqrt(discriminant) if discriminant >= 0.0 else math.nan
                ts = [0.5 * (-3.0 * k1 - root), 0.5 * (-3.0 * k1 + root)]
        positive = [t for t in ts if math.isfinite(t) and t > 0.0]  # NaN (no real root) is not > 0
        return 1.0 / max(positive) if positive else math.inf

    def distort_normalized(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply Brown-Conrady distortion to normalized image coordinates (x=X/Z, y=Y/Z)."""
        if not self.has_distortion:
            return x, y
        k1, k2, p1, p2, k3 = self.distortion
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return xd, yd

    def project(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        Sensor-frame directions (N, 3) -> pixel u, v [px] and a mask of the rays the camera images.

        In front of it (Z > 0) and, with radial distortion, within max_imaged_radius2 (beyond
        it u, v are the polynomial's fold-back, no image). Matches cv2.projectPoints with K, D.
        """
        rays = np.asarray(rays, dtype=float)
        z = rays[..., 2]
        in_front = z > 1e-9
        safe_z = np.where(in_front, z, 1.0)
        x, y = rays[..., 0] / safe_z, rays[..., 1] / safe_z
        if self.has_distortion and math.isfinite(self.max_imaged_radius2):
            in_front = in_front & (x * x + y * y <= self.max_imaged_radius2)
        x, y = self.distort_normalized(x, y)
        return self.fx * x + self.cx, self.fy * y + self.cy, in_front

    def in_image(self, u: np.ndarray, v: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Return True where (u, v) lies within the pixel area shrunk by `margin` [px]."""
        return ((u >= -0.5 + margin) & (u <= self.width - 0.5 - margin)
                & (v >= -0.5 + margin) & (v <= self.height - 0.5 - margin))

    def pixel_to_ray(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Pixel coordinates [px] -> unit direction vectors (N, 3) in the sensor frame."""
        u = np.asarray(u, dtype=float).ravel()
        v = np.asarray(v, dtype=float).ravel()
        if self.has_distortion and u.size:  # cv2.undistortPoints returns None for no points
            pts = np.stack([u, v], axis=-1).reshape(-1, 1, 2)
            und = cv2.undistortPoints(
                pts, self._k, self._d,
                criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)).reshape(-1, 2)
            x, y = und[:, 0], und[:, 1]
        else:
            x = (u - self.cx) / self.fx
            y = (v - self.cy) / self.fy
        rays = np.stack([x, y, np.ones_like(x)], axis=-1)
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def pixel_covariance_to_ray_sigma(self, cov_px: np.ndarray) -> np.ndarray:
        """
        Return the 1-sigma angular error [rad] of a ray from a 2x2 pixel covariance (N, 2, 2).

        Using the mean variance per axis and the local pixel scale (distortion neglected).
        """
        cov_px = np.asarray(cov_px, dtype=float).reshape(-1, 2, 2)
        var_px = 0.5 * (cov_px[:, 0, 0] + cov_px[:, 1, 1])
        return np.sqrt(np.maximum(var_px, 0.0)) * self.pixel_scale_rad
