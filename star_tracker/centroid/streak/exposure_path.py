# SPDX-License-Identifier: Apache-2.0
"""
The body's rotation within one exposure, from rate samples that cover it (a gyro's).

A constant rate and acceleration (SmearModel's omega t + alpha t^2 / 2) predict a star's streak
only while the motion is that smooth. Under jitter the speed and direction change within the
exposure: fitted on the smooth path, a streak's centre is pulled away from its light's mean by
0.5-4" in the same direction for every star (the stress campaign's gyro-aided jitter frames;
the same frames fitted on the true path: 0.6" rms). A gyro sampled several times per exposure
measures that path: ExposurePath integrates its samples, and SmearModel.with_exposure_path
gives the smear model that path when it departs from the smooth one by more than
PATH_MIN_DEVIATION_PX.

The path is taken relative to the exposure-average attitude, so the spots fitted on it are the
exposure-average positions: a fit on a path of the right shape puts its centre at the light's
mean whatever the gyro's noise and bias add to that mean, and jitter within an exposure is not
otherwise observable from the image (the frame is judged against its exposure-average attitude,
as without a gyro).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_SAMPLES_INSIDE = 3  # rate samples within the exposure a path needs (fewer: no shape to speak of)
KNOTS = 65  # times across the exposure the path is integrated at
PATH_MIN_DEVIATION_PX = 0.02  # a path departing less from the smooth model's is not used [px]
# (a gyro of 0.005 deg/s per sample at 100 Hz wanders 0.4" = 0.008 px in half a 0.1 s exposure
# of a 15 deg 1024 px camera; 20" of jitter at 20 Hz departs by up to 0.4 px)
SAMPLES_PER_RATE_SAMPLE = 4  # path samples per rate sample inside the exposure (SmearModel.path),
MAX_PATH_SAMPLES = 48  # up to this many (the streak fits' grouping compares samples pairwise)
PROBE_FRACTION = 0.45  # deviation probed at the centre and at these fractions of the field toward its corners
# Streaks fitted on a path keep an error common to every star of up to a few percent of the
# exposure's offset from mid-exposure (ExposurePath.mid_exposure_offset_rad): the frame's PSF
# estimate includes the path's spread on short streaks. Stated as this fraction of it, 1 sigma per
# axis (AppliedMotion.path_residual_covariance): on the independent renderer's jittered frames
# (test_exposure_path) it takes the common error's chi^2_2 from up to 123 to at most 3.0.
PATH_FIT_RESIDUAL_FRACTION = 0.015


@dataclass(frozen=True, eq=False)
class ExposurePath:
    """
    Rotation vectors phi(t) [rad] of the body within one exposure, in the sensor frame.

    times_s: (K,) increasing, from -exposure_s / 2 to +exposure_s / 2 [s from mid-exposure];
    rotation_vectors_rad: (K, 3) phi(t_k), with a time mean of zero over the exposure (the
    attitude is R(t) = R_mean exp([phi(t) x]), R_mean the exposure-average attitude);
    samples: the rate samples inside the exposure it was integrated from.
    """

    times_s: np.ndarray
    rotation_vectors_rad: np.ndarray
    samples: int

    @classmethod
    def from_rate_samples(cls, offsets_s, rates_rad_s, exposure_s: float) -> "ExposurePath | None":
        """
        Integrate body-rate samples over the exposure; None without MIN_SAMPLES_INSIDE of them inside it.

        offsets_s: (n,) sample times [s] from mid-exposure; rates_rad_s: (n, 3) [rad/s] in the
        sensor frame. The rate is interpolated linearly between samples and held constant
        beyond the first and last (samples outside the exposure help at its ends).
        """
        t = np.asarray(offsets_s, float).ravel()
        w = np.asarray(rates_rad_s, float).reshape(-1, 3)
        exposure = float(exposure_s)
        if t.size != w.shape[0] or not (np.isfinite(exposure) and exposure > 0):
            raise ValueError(f"expected n offsets and (n, 3) rates with exposure_s > 0, got {t.size}, "
                             f"{w.shape}, {exposure_s!r}")
        finite = np.isfinite(t) & np.all(np.isfinite(w), axis=1)
        t, w = t[finite], w[finite]
        inside = int(np.count_nonzero(np.abs(t) <= 0.5 * exposure))
        if inside < MIN_SAMPLES_INSIDE:
            return None
        order = np.argsort(t, kind="stable")
        t, w = t[order], w[order]
        knots = np.linspace(-0.5 * exposure, 0.5 * exposure, KNOTS)
        omega = np.column_stack([np.interp(knots, t, w[:, axis]) for axis in range(3)])
        steps = 0.5 * (omega[1:] + omega[:-1]) * np.diff(knots)[:, None]
        phi = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
        # The time mean (trapezoid) is the exposure-average attitude's offset.
        mean = np.sum(0.5 * (phi[1:] + phi[:-1]) * np.diff(knots)[:, None], axis=0) / exposure
        phi = phi - mean
        knots.flags.writeable = False
        phi.flags.writeable = False
        return cls(knots, phi, inside)

    @property
    def mid_exposure_offset_rad(self) -> np.ndarray:
        """phi(0) (3,) [rad]: the mid-exposure attitude from the exposure average, R_mid = R_mean exp([phi(0) x])."""
        return self.at(np.zeros(1))[0]

    @property
    def fit_samples(self) -> int:
        """The fewest samples SmearModel.path takes along this path (SAMPLES_PER_RATE_SAMPLE per rate sample)."""
        return min(SAMPLES_PER_RATE_SAMPLE * self.samples, MAX_PATH_SAMPLES)

    def at(self, times_s) -> np.ndarray:
        """Return phi (M, 3) [rad] at `times_s` (M,) [s from mid-exposure] (held beyond the exposure)."""
        t = np.asarray(times_s, float).ravel()
        return np.column_stack([np.interp(t, self.times_s, self.rotation_vectors_rad[:, axis]) for axis in range(3)])
