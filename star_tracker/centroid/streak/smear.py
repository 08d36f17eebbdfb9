# SPDX-License-Identifier: Apache-2.0
"""
Smear geometry: where a fixed star's image moves on the detector during one exposure.

Under a body rate and, when known, a constant angular acceleration or the path a gyro measured
within the exposure (SmearModel); and the length of a straight streak from its second moment.

Image convention: pixel (0, 0) is the centre of the top-left pixel; x = column, y = row [px].
Angles are measured from +x toward +y (clockwise on the displayed image, y down) [rad].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ...models.camera import CameraModel
from .exposure_path import KNOTS, PATH_MIN_DEVIATION_PX, PROBE_FRACTION, ExposurePath

PATH_SPACING_PX = 0.5  # SmearModel.path's default: samples at most this far apart [px]


def segment_length(major, sigma: float) -> np.ndarray:
    """
    Return the length [px] of a straight streak from its second moment `major` [px^2] along it.

    The streak's image is a segment swept by a Gaussian PSF of 1-sigma `sigma` [px]: a uniform
    segment of length L adds L^2 / 12. 0 where `major` is below sigma^2 (NaN stays NaN).
    """
    return np.sqrt(np.maximum(12.0 * (np.asarray(major, dtype=float) - sigma * sigma), 0.0))


@dataclass(frozen=True, eq=False)
class SmearModel:
    """
    Image motion of fixed stars during one exposure under a body rate and angular acceleration.

    camera: sensor geometry (distortion included); angular_velocity_rad_s: (3,) body rate
    omega in the sensor frame [rad/s] (+Z boresight, +X right, +Y down) at mid-exposure;
    exposure_s: exposure time [s]; angular_acceleration_rad_s2: (3,) d omega/dt alpha in the
    sensor frame [rad/s^2] (None: zero, a constant rate). A star's sensor-frame direction at
    time t from mid-exposure is s(t) = exp(-[phi(t) x]) s(0), phi(t) = omega t + alpha t^2 / 2,
    the attitude being R(t) = R_mid exp([phi(t) x]) (to second order in t: the omega x alpha
    term of the exact composition is below 1e-3 px over a 0.1 s exposure at 10 deg/s and 10
    deg/s^2). Under an acceleration the image moves unevenly: the path samples (evenly spaced
    in time) crowd where it is slow, so a path fit gives the mid-exposure position, and a
    point-like spot's centroid (the exposure-average direction) lies exposure_mean_offset from
    it (alpha T^2 / 24 for a star that does not otherwise move).

    exposure_path: the rotation a gyro measured within the exposure (exposure_path.py,
    with_exposure_path), in place of omega and alpha (which must then be None); its phi(t) is relative to the
    exposure-average attitude, so the positions the path is drawn from, and a path fit's
    result, are the exposure-average ones (exposure_mean_offset about zero).
    angular_velocity_rad_s stays the exposure's mean rate.
    """

    camera: CameraModel
    angular_velocity_rad_s: np.ndarray
    exposure_s: float
    angular_acceleration_rad_s2: np.ndarray | None = None
    exposure_path: ExposurePath | None = None

    def __post_init__(self) -> None:
        if not all(callable(getattr(self.camera, m, None)) for m in ("project", "pixel_to_ray")):
            raise ValueError(f"camera must be a CameraModel (project, pixel_to_ray), got {self.camera!r}")
        try:
            omega = np.array(self.angular_velocity_rad_s, dtype=float)
            exposure = float(self.exposure_s)
        except (TypeError, ValueError):
            raise ValueError("angular_velocity_rad_s must be 3 numbers [rad/s] and exposure_s a number [s]") from None
        if omega.shape != (3,) or not np.all(np.isfinite(omega)):
            raise ValueError("angular_velocity_rad_s must be 3 finite values [rad/s], "
                             f"got {self.angular_velocity_rad_s!r}")
        if not (np.isfinite(exposure) and exposure >= 0):
            raise ValueError(f"exposure_s must be finite and >= 0 [s], got {self.exposure_s!r}")
        omega.flags.writeable = False
        object.__setattr__(self, "angular_velocity_rad_s", omega)
        if self.angular_acceleration_rad_s2 is not None:
            try:
                alpha = np.array(self.angular_acceleration_rad_s2, dtype=float)
            except (TypeError, ValueError):
                raise ValueError("angular_acceleration_rad_s2 must be 3 numbers [rad/s^2]") from None
            if alpha.shape != (3,) or not np.all(np.isfinite(alpha)):
                raise ValueError("angular_acceleration_rad_s2 must be 3 finite values [rad/s^2], "
                                 f"got {self.angular_acceleration_rad_s2!r}")
            alpha.flags.writeable = False
            object.__setattr__(self, "angular_acceleration_rad_s2", alpha if np.any(alpha) else None)
        object.__setattr__(self, "exposure_s", exposure)
        if self.exposure_path is not None:
            if not isinstance(self.exposure_path, ExposurePath):
                raise ValueError(f"exposure_path must be an ExposurePath, got {self.exposure_path!r}")
            if self.angular_acceleration_rad_s2 is not None:
                raise ValueError("a smear model with an exposure_path takes no angular_acceleration_rad_s2")

    def sample_times(self, samples: int) -> np.ndarray:
        """Mid-points of `samples` equal slices of the exposure, from mid-exposure [s]."""
        return ((np.arange(samples) + 0.5) / samples - 0.5) * self.exposure_s

    def _positions(self, x, y, times: np.ndarray) -> np.ndarray:
        """
        Offsets (N, K, 2) [px] at `times` [s from mid-exposure] from the stars' reference pixels (x, y).

        (x, y): mid-exposure positions, or exposure-average ones with an exposure_path.
        """
        x, y = _pixels(x, y)
        rays = self.camera.pixel_to_ray(x, y)  # (N, 3) directions at the reference time
        u0, v0, _ = self.camera.project(rays)  # reference: cancels the undistortion round trip
        if self.exposure_path is not None:
            phi = self.exposure_path.at(times)
        else:
            phi = np.multiply.outer(times, self.angular_velocity_rad_s)
        if self.angular_acceleration_rad_s2 is not None:
            phi = phi + 0.5 * np.multiply.outer(times * times, self.angular_acceleration_rad_s2)
        turns = Rotation.from_rotvec(-phi).as_matrix()  # (K, 3, 3)
        u, v, in_front = self.camera.project(np.einsum("kij,nj->nki", turns, rays))
        offsets = np.stack([u - u0[:, None], v - v0[:, None]], axis=-1)
        return np.where(in_front[..., None], offsets, np.nan)  # behind the camera: no image

    def path(self, x, y, samples: int | None = None) -> np.ndarray:
        """
        Pixel offsets (N, K, 2) [px] of the star images whose mid-exposure positions are (x, y) [px].

        At the K times t_k = ((k + 0.5) / K - 0.5) exposure_s, relative to (x, y) (zero at t =
        0, antisymmetric for straight constant-speed smear; with an exposure_path (x, y) are the
        exposure-average positions and the offsets' mean is zero). samples: K; default the
        fewest giving <= PATH_SPACING_PX between samples along the longest path (>= 1; with an
        exposure_path at least exposure_path.SAMPLES_PER_RATE_SAMPLE per rate sample inside the
        exposure, so a jitter's swings between them are drawn). NaN where the direction is
        behind the camera.
        """
        if samples is None:
            probe = self._positions(x, y, self.sample_times(16))
            longest = np.nan_to_num(np.sum(np.linalg.norm(np.diff(probe, axis=1), axis=2), axis=1)) * 16 / 15
            samples = max(1, int(np.ceil(float(np.max(longest, initial=0.0)) / PATH_SPACING_PX)),
                          0 if self.exposure_path is None else self.exposure_path.fit_samples)
        elif not (isinstance(samples, (int, np.integer)) and samples >= 1):
            raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
        return self._positions(x, y, self.sample_times(int(samples)))

    def with_exposure_path(self, offsets_s, rates_rad_s, rate_noise_rad_s: float = 0.0) -> "SmearModel":
        """
        Return this model on the path rate samples measure, when it departs from this one's by PATH_MIN_DEVIATION_PX.

        offsets_s (n,) [s from mid-exposure] and rates_rad_s (n, 3) [rad/s, sensor frame]: the
        samples around the exposure (a gyro's; exposure_path.py); rate_noise_rad_s: each
        sample's white noise, 1 sigma per axis [rad/s] (ExposurePath.mid_exposure_offset_covariance).
        The departure: the largest distance between the two models' image positions (each
        relative to its exposure mean) at the field's centre and toward its corners. Otherwise (fewer than
        exposure_path.MIN_SAMPLES_INSIDE samples inside, or a path as smooth as this model's)
        this model itself.
        """
        if self.exposure_path is not None or self.exposure_s <= 0:
            return self
        path = ExposurePath.from_rate_samples(offsets_s, rates_rad_s, self.exposure_s, rate_noise_rad_s)
        if path is None:
            return self
        measured = SmearModel(self.camera, self.angular_velocity_rad_s, self.exposure_s, exposure_path=path)
        width, height = self.camera.width, self.camera.height
        cx, cy = 0.5 * (width - 1), 0.5 * (height - 1)
        dx, dy = PROBE_FRACTION * width, PROBE_FRACTION * height
        x = cx + np.array([0.0, -dx, dx, -dx, dx])
        y = cy + np.array([0.0, -dy, -dy, dy, dy])
        times = self.sample_times(2 * KNOTS)
        smooth = self._positions(x, y, times)
        smooth = smooth - np.nanmean(smooth, axis=1, keepdims=True)
        departure = np.nanmax(np.linalg.norm(measured._positions(x, y, times) - smooth, axis=2), initial=0.0)
        return measured if departure > PATH_MIN_DEVIATION_PX else self

    def exposure_mean_offset(self, x, y) -> np.ndarray:
        """
        Return the exposure-average image position minus the mid-exposure one (N, 2) [px].

        Of the stars at mid-exposure pixels (x, y) [px]: where a point-like spot's centroid
        lies from its mid-exposure position (the mean over 32 equal time slices: exact to
        1e-3 of the offset for a quadratic path). Zero without an acceleration, but for an
        arc's curvature under roll; about zero with an exposure_path (its positions are the
        exposure averages).
        """
        return np.nanmean(self._positions(x, y, self.sample_times(32)), axis=1)

    def smear_vectors(self, x, y) -> np.ndarray:
        """
        Return the end minus start image position (N, 2) [px] over the exposure (t = +T/2 and -T/2).

        Of the stars at mid-exposure pixels (x, y) [px].
        """
        ends = self._positions(x, y, np.array([-0.5, 0.5]) * self.exposure_s)
        return ends[:, 1] - ends[:, 0]


def _pixels(x, y) -> tuple[np.ndarray, np.ndarray]:
    try:
        x = np.asarray(x, dtype=float).ravel()
        y = np.asarray(y, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError("pixel coordinates x, y must be numeric") from None
    if x.shape != y.shape:
        raise ValueError(f"x and y must have the same number of values, got {x.size} and {y.size}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("pixel coordinates x, y must be finite")
    return x, y
