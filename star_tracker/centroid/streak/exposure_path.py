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
mean whatever the gyro's noise and bias add to that mean. The path's own offset of
mid-exposure from that mean, phi(0) (mid_exposure_offset_rad), then carries the frame's
attitude to mid-exposure (the tracker: R_mid = R_mean exp([phi(0) x])), with its covariance
(mid_exposure_offset_covariance): what the gyro's noise leaves in phi(0) (a bias moves it by
nothing, its time mean being zero) and what the interpolation and the fit on the path leave
(PATH_FIT_RESIDUAL_FRACTION).

The rate is interpolated between samples by a cubic spline: under a 20 Hz jitter sampled at
100 Hz, straight lines between samples lose about a fifth of the swing, enough to put phi(0)
several times its stated error off (the stress campaign's gyro-aided jitter frames).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable

import numpy as np
from scipy.interpolate import CubicSpline

MIN_SAMPLES_INSIDE = 3  # rate samples within the exposure a path needs (fewer: no shape to speak of)
KNOTS = 65  # times across the exposure the path is integrated at (odd: the middle one is mid-exposure)
PATH_MIN_DEVIATION_PX = 0.02  # a path departing less from the smooth model's is not used [px]
# (a gyro of 0.005 deg/s per sample at 100 Hz wanders 0.4" = 0.008 px in half a 0.1 s exposure
# of a 15 deg 1024 px camera; 20" of jitter at 20 Hz departs by up to 0.4 px)
SAMPLES_PER_RATE_SAMPLE = 4  # path samples per rate sample inside the exposure (SmearModel.path),
MAX_PATH_SAMPLES = 48  # up to this many (the streak fits' grouping compares samples pairwise)
PROBE_FRACTION = 0.45  # deviation probed at the centre and at these fractions of the field toward its corners
# A frame carried to mid-exposure by phi(0) keeps an error common to every star that grows with
# |phi(0)|: its streaks' fit on the path (the frame's PSF estimate includes the path's spread on
# short streaks) and phi(0)'s interpolation between gyro samples (a 19 Hz jitter sampled at
# 100 Hz: up to 1.2 % of it). Stated as this fraction of |phi(0)|, 1 sigma per axis, with the
# terms below (ExposurePath.mid_exposure_offset_covariance): on the independent renderer's
# jittered frames (test_exposure_path) the mid-exposure error's chi^2_2 is at most 8.1 with
# them (136 without; with 0.5 % here, 23).
PATH_FIT_RESIDUAL_FRACTION = 0.01
# How far phi(0) is off where the samples do not resolve the motion: each interior sample within
# the exposure predicted by the spline through the others, their rms error e [rad/s], gives
# phi(0)'s error as this gain times e times the sample spacing, 1 sigma per axis. On 20"
# sinusoids sampled at 2.6-10 samples per period (10-25 Hz at 50 and 100 Hz) the largest error
# over phases is 0.16-0.65 of the sigma stated (test_exposure_path; at 19 Hz and 50 Hz up to
# 1.65" off); jitter above half the sample rate is not seen at all.
INTERPOLATION_ERROR_GAIN = 0.1


@dataclass(frozen=True, eq=False)
class ExposurePath:
    """
    Rotation vectors phi(t) [rad] of the body within one exposure, in the sensor frame.

    times_s: (K,) increasing, from -exposure_s / 2 to +exposure_s / 2 [s from mid-exposure];
    rotation_vectors_rad: (K, 3) phi(t_k), with a time mean of zero over the exposure (the
    attitude is R(t) = R_mean exp([phi(t) x]), R_mean the exposure-average attitude);
    samples: the rate samples inside the exposure it was integrated from;
    offset_covariance: returns mid_exposure_offset_covariance (computed when first read: a
    path SmearModel.with_exposure_path does not keep never needs it).
    """

    times_s: np.ndarray
    rotation_vectors_rad: np.ndarray
    samples: int
    offset_covariance: Callable[[], np.ndarray] = field(repr=False)

    @cached_property
    def mid_exposure_offset_covariance(self) -> np.ndarray:
        """
        (3, 3) [rad^2] of phi(0) as the frame's offset to mid-exposure (from_rate_samples).

        The samples' noise through the integration, PATH_FIT_RESIDUAL_FRACTION and what the
        samples leave unresolved (INTERPOLATION_ERROR_GAIN).
        """
        covariance = self.offset_covariance()
        covariance.flags.writeable = False
        return covariance

    @classmethod
    def from_rate_samples(cls, offsets_s, rates_rad_s, exposure_s: float,
                          rate_noise_rad_s: float = 0.0) -> "ExposurePath | None":
        """
        Integrate body-rate samples over the exposure; None without MIN_SAMPLES_INSIDE of them inside it.

        None as well when either end of the exposure is more than the samples' median spacing
        from the nearest sample (the samples do not cover it).

        offsets_s: (n,) sample times [s] from mid-exposure; rates_rad_s: (n, 3) [rad/s] in the
        sensor frame; rate_noise_rad_s: each sample's white noise, 1 sigma per axis [rad/s]. The
        rate is interpolated by a cubic spline through the samples (not-a-knot; a repeated time
        keeps its first sample) and held constant beyond the first and last (samples outside
        the exposure help at its ends). phi(0) is linear in the samples, phi(0) = sum_i c_i w_i,
        so the noise's part of its covariance is rate_noise^2 sum_i c_i^2 per axis, exactly for
        this interpolation; (PATH_FIT_RESIDUAL_FRACTION |phi(0)|)^2 and the interpolation's
        (INTERPOLATION_ERROR_GAIN e dt)^2 per axis are added (e: the samples' left-out error, dt:
        their median spacing).
        """
        t = np.asarray(offsets_s, float).ravel()
        w = np.asarray(rates_rad_s, float).reshape(-1, 3)
        exposure = float(exposure_s)
        noise = float(rate_noise_rad_s)
        if t.size != w.shape[0] or not (np.isfinite(exposure) and exposure > 0) \
                or not (np.isfinite(noise) and noise >= 0):
            raise ValueError(f"expected n offsets and (n, 3) rates with exposure_s > 0 and rate_noise_rad_s >= 0, "
                             f"got {t.size}, {w.shape}, {exposure_s!r}, {rate_noise_rad_s!r}")
        finite = np.isfinite(t) & np.all(np.isfinite(w), axis=1)
        t, first = np.unique(t[finite], return_index=True)
        w = w[finite][first]
        inside = int(np.count_nonzero(np.abs(t) <= 0.5 * exposure))
        if inside < MIN_SAMPLES_INSIDE:
            return None
        # Each end of the exposure within a sample spacing of a sample: the rate is held beyond
        # the last, so a missing one (a gyro message not yet received) would leave a guess.
        spacing = float(np.median(np.diff(t)))
        if t[0] > -0.5 * exposure + spacing or t[-1] < 0.5 * exposure - spacing:
            return None
        knots = np.linspace(-0.5 * exposure, 0.5 * exposure, KNOTS)
        # Integrated for the samples' unit vectors at once: the weights of each sample in phi(t).
        weights = _integrated(CubicSpline(t, np.eye(t.size), axis=0)(np.clip(knots, t[0], t[-1])), knots, exposure)
        phi = weights @ w
        at_mid = weights[KNOTS // 2]  # each sample's weight in phi(0)

        def offset_covariance() -> np.ndarray:
            residual = PATH_FIT_RESIDUAL_FRACTION * float(np.linalg.norm(at_mid @ w))
            unresolved = INTERPOLATION_ERROR_GAIN * _left_out_error(t, w, exposure) * spacing
            return np.eye(3) * (noise * noise * float(at_mid @ at_mid) + residual * residual + unresolved * unresolved)

        knots.flags.writeable = False
        phi.flags.writeable = False
        return cls(knots, phi, inside, offset_covariance)

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


def _left_out_error(t: np.ndarray, w: np.ndarray, exposure: float) -> float:
    """
    Return the rms left-out error [rad/s, per axis] of the interior samples within the exposure.

    Each sample predicted by the cubic spline through the others.
    """
    errors = [CubicSpline(np.delete(t, i), np.delete(w, i, axis=0), axis=0)(t[i]) - w[i]
              for i in range(1, t.size - 1) if abs(t[i]) <= 0.5 * exposure]
    return float(np.sqrt(np.mean(np.square(errors)))) if errors else 0.0


def _integrated(omega: np.ndarray, knots: np.ndarray, exposure: float) -> np.ndarray:
    """Return the integral phi (K, m) of omega (K, m) over knots (trapezoid), less its time mean over the exposure."""
    steps = 0.5 * (omega[1:] + omega[:-1]) * np.diff(knots)[:, None]
    phi = np.vstack([np.zeros((1, omega.shape[1])), np.cumsum(steps, axis=0)])
    mean = np.sum(0.5 * (phi[1:] + phi[:-1]) * np.diff(knots)[:, None], axis=0) / exposure
    return phi - mean
