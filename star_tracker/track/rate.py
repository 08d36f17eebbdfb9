# SPDX-License-Identifier: Apache-2.0
"""
Body angular velocity from successive attitudes (and, when stars are smeared, from streaks).

Model: over a short window the body rate is constant, so the attitudes R_i (sensor -> ICRS)
at times t_i follow R(t) = R_ref exp([a + omega (t - t_ref)]x) with omega in the sensor
frame. Each solution has a small-angle error covariance P_i (sensor frame). Generalised least
squares over (a, omega) with weights P_i^-1 gives omega and its covariance.

With four or more attitudes in the window the model adds a constant angular acceleration
(phi = a + omega tau + alpha tau^2 / 2), so the rate at the newest frame stays unbiased while
the body accelerates. With two or three the constant-rate slope is the rate at the window's
weighted mean time, not at the newest frame: with |d omega/dt| <= alpha_max (a stated
assumption, `max_angular_acceleration_rad_s2`) that bias is at most alpha_max (t_newest -
t_mean) per axis, and its variance, as a uniform error, is added to the covariance. A window
whose residuals fail a chi^2 test (the acceleration changed inside it, or an attitude is
biased) is shortened from the old end until the fit passes.

The estimate carries the angular acceleration and its covariance (RateEstimate) only from a
constant-acceleration fit whose chi^2 tests passed (four attitudes or more). A rate-aided
centroider needs it: under an acceleration the smear is uneven in time and a spot's centroid is
the exposure average, not the mid-exposure position (centroid/streak/smear.py), so a wrong
acceleration moves every spot. When the window is shorter but three attitudes are in it, the
exact quadratic through the newest three carries the constant-rate slope over its lag to the
newest frame; its acceleration, untested, is not published: under jitter the window shortens
every frame and that quadratic is the jitter's aliased curvature, whose alpha T^2 / 24 moved
every spot of the next frame by several of its stated sigmas (stress campaign).

Each attitude is what its frame measured: where the centroider's acceleration A_k (None: 0)
missed the body's alpha, the spots, and so the attitude, moved by g_k (alpha - A_k), g_k the
frame's bias gain [s^2] (Tracker.bias_gain: T^2 / 24 for point-like spots, more for streaks).
The fit takes it in: the attitude turned back by g_k A_k, the acceleration's basis
tau^2 / 2 + g_k. A window of frames measured with and without an acceleration (the first
frames of a slew, before the rate estimate holds one) then fits one motion, where the bare
model saw a step of g alpha (3" at 2 deg/s^2) and shortened the window every frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit
from scipy.special import gammaincinv

from ..models.attitude import matrix_to_rotation_vector, rotation_vector_to_matrix

# A rate-aided centroider uses an angular acceleration only from an estimate (or rate samples)
# no older than this before the frame: after a gap the motion may have changed unseen (a slew
# stopping or starting). The tracker takes the same age for what the centroider had
# (Tracker.acceleration_covariance), the centroider's rate input for its samples
# (ros/rate_input.RateSamples.motion_for_frame).
ACCELERATION_MAX_AGE_S = 0.5


@dataclass(frozen=True)
class RateEstimate:
    """
    angular_velocity.

    (3,) body rate in the sensor frame [rad/s] at `stamp_ns`; covariance: (3, 3)
    [rad^2/s^2]; frames: attitudes used; angular_acceleration: (3,) d omega/dt in the sensor
    frame [rad/s^2] and acceleration_covariance (3, 3) [rad^2/s^4], from the constant-
    acceleration fit of a window of four attitudes or more that passed its tests; None
    otherwise (a shorter window's rate, the constant-rate slope, is carried to stamp_ns by the
    newest three's exact quadratic, and the lag's bound (alpha_max lag)^2 / 3 per axis stays in
    covariance).
    """

    stamp_ns: int
    angular_velocity: np.ndarray
    covariance: np.ndarray
    frames: int
    angular_acceleration: np.ndarray | None = None
    acceleration_covariance: np.ndarray | None = None

    @property
    def sigma(self) -> np.ndarray:
        """(3,) 1-sigma per sensor axis [rad/s]."""
        return np.sqrt(np.diag(self.covariance))

    def at(self, stamp_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """
        Return (rate [rad/s], acceleration [rad/s^2]) extrapolated to `stamp_ns`.

        The rate moved on by the acceleration (zero when not estimated): what a smear model of
        a later frame needs (SmearModel).
        """
        if self.angular_acceleration is None:
            return self.angular_velocity.copy(), np.zeros(3)
        dt = (int(stamp_ns) - self.stamp_ns) * 1e-9
        return self.angular_velocity + self.angular_acceleration * dt, self.angular_acceleration.copy()


class AttitudeRateEstimator:
    """Sliding-window rate estimate from verified attitudes (oldest dropped after `window_s`)."""

    def __init__(self, window_s: float = 0.35, max_angular_acceleration_rad_s2: float = np.radians(1.0),
                 max_frames: int = 8):
        if not (window_s > 0 and max_angular_acceleration_rad_s2 >= 0 and max_frames >= 2):
            raise ValueError(f"invalid rate estimator settings: window_s={window_s}, "
                             f"max_angular_acceleration_rad_s2={max_angular_acceleration_rad_s2}, "
                             f"max_frames={max_frames}")
        self.window_ns = int(window_s * 1e9)
        self.alpha_max = float(max_angular_acceleration_rad_s2)
        # The window, oldest first, in arrays (the fit is compiled): stamps [ns], rotations
        # (sensor -> ICRS), information P^-1 [1/rad^2] and covariance P [rad^2].
        self._count = 0
        self._stamps = np.zeros(max_frames, np.int64)
        self._rotations = np.zeros((max_frames, 3, 3))
        self._information = np.zeros((max_frames, 3, 3))
        self._covariances = np.zeros((max_frames, 3, 3))
        self._gains = np.zeros(max_frames)  # g_k [s^2] (module docstring)
        self._limits = _chi2_limits(3 * max_frames)

    def reset(self) -> None:
        self._count = 0

    def add(self, stamp_ns: int, rotation: np.ndarray, covariance: np.ndarray, bias_gain_s2: float = 0.0,
            applied_acceleration: np.ndarray | None = None) -> RateEstimate | None:
        """
        Add a verified attitude; return the rate at `stamp_ns` once two attitudes are in the window, else None.

        Stamps must increase; an older one restarts the window. bias_gain_s2: g [s^2], how far
        an acceleration the frame's centroider missed moved its attitude per rad/s^2;
        applied_acceleration: the acceleration it used [rad/s^2, sensor frame] (None: none)
        (module docstring).
        """
        stamp_ns = int(stamp_ns)
        if self._count and stamp_ns <= self._stamps[self._count - 1]:
            self._count = 0
        covariance = np.ascontiguousarray(covariance, float).reshape(3, 3)
        invertible, information = _inverse3(covariance)
        if not invertible:
            raise ValueError("attitude covariance must be invertible")
        gain = float(bias_gain_s2)
        if not (math.isfinite(gain) and gain >= 0.0):
            raise ValueError(f"bias_gain_s2 must be finite and >= 0 [s^2], got {bias_gain_s2!r}")
        if applied_acceleration is not None and gain > 0.0:
            # Back to what the frame would have measured without it: R exp([g A x]).
            rotation = np.asarray(rotation, float) @ rotation_vector_to_matrix(
                gain * np.asarray(applied_acceleration, float).reshape(3))
        # Oldest out: beyond the window, or to make room.
        drop = int(np.count_nonzero(stamp_ns - self._stamps[:self._count] > self.window_ns))
        drop = max(drop, self._count + 1 - self._stamps.size)
        if drop:
            kept = slice(drop, self._count)
            for array in (self._stamps, self._rotations, self._information, self._covariances, self._gains):
                array[:self._count - drop] = array[kept]
            self._count -= drop
        k = self._count
        self._stamps[k], self._rotations[k], self._information[k], self._covariances[k], self._gains[k] = (
            stamp_ns, rotation, information, covariance, gain)
        self._count += 1
        return self.estimate()

    def estimate(self) -> RateEstimate | None:
        """
        Return the rate at the newest attitude.

        The longest window (newest frames) whose fit passes two chi^2 tests at 1 % (all
        residuals; the newest attitude's own residual, which an acceleration change since the
        previous frame shows first); a failed test drops the oldest attitude and refits, down
        to two.
        """
        count = self._count
        if count < 2:
            return None
        stamps = self._stamps[:count]
        # Rotation vectors relative to the newest attitude, in the newest sensor frame.
        phi = _relative_rotation_vectors(self._rotations[:count])
        tau = (stamps - stamps[-1]) * 1e-9
        gains = self._gains[:count]
        ok, omega, covariance, frames, alpha, alpha_cov, lag = _window_fit(
            tau, phi, gains, self._information[:count], self._covariances[count - 1], self.alpha_max, self._limits)
        if not ok:
            return None
        if frames < 4:
            if count < 3:
                return RateEstimate(int(stamps[-1]), omega, covariance, int(frames))
            # The newest three attitudes fix a constant acceleration exactly. It carries the
            # constant-rate slope over its lag to the newest frame; the lag's bound stays in the
            # covariance (the acceleration may have changed inside the three frames). Untested,
            # the acceleration itself is not published (module docstring).
            ok3, _, _, _, _, alpha, alpha_cov = _gls(tau[-3:], phi[-3:], gains[-3:], self._information[count - 3:count],
                                                     self._covariances[count - 1], 3)
            if ok3:
                omega = omega + alpha * lag
                covariance = covariance + lag * lag * alpha_cov
            return RateEstimate(int(stamps[-1]), omega, covariance, int(frames))
        return RateEstimate(int(stamps[-1]), omega, covariance, int(frames), alpha, alpha_cov)


@lru_cache(maxsize=8)
def _chi2_limits(max_dof: int) -> np.ndarray:
    """1 % upper tail of chi^2 for 0..max_dof degrees of freedom (0: no test)."""
    limits = np.full(max_dof + 1, np.inf)
    # scipy.stats.chi2.ppf(0.99, dof) is exactly this (chi2_gen._ppf); importing scipy.stats
    # cost the identifier's start ~2 s.
    limits[1:] = 2.0 * gammaincinv(np.arange(1, max_dof + 1) / 2, 0.99)
    return limits


def _relative_rotation_vectors(rotations: np.ndarray) -> np.ndarray:
    """
    Return the (k, 3) rotation vectors [rad] of R_newest^T R_k for (k, 3, 3) rotations (newest last).

    From the antisymmetric part (compiled; exact below pi/2, which a rate window never
    approaches; larger angles fall back to matrix_to_rotation_vector).
    """
    phi, small = _relative_small_rotation_vectors(np.ascontiguousarray(rotations, dtype=float))
    if small:
        return phi
    return np.array([matrix_to_rotation_vector(rotations[-1].T @ r) for r in rotations])


@njit(cache=True)
def _relative_small_rotation_vectors(rotations):
    count = rotations.shape[0]
    newest = rotations[count - 1]
    phi = np.empty((count, 3))
    rel = np.empty((3, 3))
    for k in range(count):
        for i in range(3):
            for j in range(3):
                rel[i, j] = newest[0, i] * rotations[k, 0, j] + newest[1, i] * rotations[k, 1, j] \
                    + newest[2, i] * rotations[k, 2, j]
        sx = 0.5 * (rel[2, 1] - rel[1, 2])
        sy = 0.5 * (rel[0, 2] - rel[2, 0])
        sz = 0.5 * (rel[1, 0] - rel[0, 1])
        cos = 0.5 * (rel[0, 0] + rel[1, 1] + rel[2, 2] - 1.0)
        if cos < 0.0:
            return phi, False
        sin = math.sqrt(sx * sx + sy * sy + sz * sz)
        scale = math.atan2(sin, cos) / sin if sin > 1e-12 else 1.0
        phi[k, 0], phi[k, 1], phi[k, 2] = sx * scale, sy * scale, sz * scale
    return phi, True


@njit(cache=True)
def _inverse3(matrix):
    """(invertible, inverse) of a 3x3 matrix by cofactors (compiled: once per tracked frame)."""
    m = matrix
    inverse = np.empty((3, 3))
    inverse[0, 0] = m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]
    inverse[0, 1] = m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2]
    inverse[0, 2] = m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]
    inverse[1, 0] = m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2]
    inverse[1, 1] = m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0]
    inverse[1, 2] = m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]
    inverse[2, 0] = m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]
    inverse[2, 1] = m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1]
    inverse[2, 2] = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    det = m[0, 0] * inverse[0, 0] + m[0, 1] * inverse[1, 0] + m[0, 2] * inverse[2, 0]
    if not (det != 0.0 and math.isfinite(det)):
        return False, inverse
    inverse /= det
    for i in range(3):
        for j in range(3):
            if not math.isfinite(inverse[i, j]):
                return False, inverse
    return True, inverse


@njit(cache=True)
def _window_fit(tau, phi, gains, weight, newest_covariance, alpha_max, limits):
    """
    estimate()'s window loop.

    GLS fits of phi(tau) [rad] at times tau [s] (newest last, tau = 0), bias gains g [s^2], with weights P^-1,
    from the whole window down to the newest two until both chi^2 tests pass (limits[dof]).
    With 4+ attitudes the fit includes a constant acceleration, so the rate at the newest
    frame is unbiased while the body accelerates; with 2-3 it is the constant-rate fit, whose
    slope is the rate at the weighted mean time: its lag times alpha_max is added to the
    covariance. Returns (ok, omega [rad/s], covariance, frames, alpha [rad/s^2], its
    covariance, lag [s]: how long before the newest frame the rate refers to); alpha and its
    covariance are zero and lag > 0 when the fit had no acceleration term.
    """
    count = tau.size
    for first in range(count - 1):
        frames = count - first
        terms = 3 if frames >= 4 else 2
        lag = 0.0
        ok, omega, covariance, chi2, newest_chi2, alpha, alpha_cov = _gls(tau[first:], phi[first:], gains[first:],
                                                                          weight[first:], newest_covariance, terms)
        if not ok:
            return False, omega, covariance, 0, alpha, alpha_cov, 0.0
        if terms == 2:
            trace_sum = 0.0
            weighted = 0.0
            for k in range(first, count):
                trace = weight[k, 0, 0] + weight[k, 1, 1] + weight[k, 2, 2]
                trace_sum += trace
                weighted += trace * tau[k]
            lag = -weighted / trace_sum
            for i in range(3):
                covariance[i, i] += (alpha_max * lag) ** 2 / 3.0
        dof = 3 * frames - 3 * terms
        if ((dof == 0 or chi2 <= limits[dof]) and newest_chi2 <= limits[3]) or frames == 2:
            return True, omega, covariance, frames, alpha, alpha_cov, lag
    return False, np.zeros(3), np.zeros((3, 3)), 0, np.zeros(3), np.zeros((3, 3)), 0.0


@njit(cache=True)
def _gls(tau, phi, gains, weight, newest_covariance, terms):
    """
    phi_k = sum_a basis_a(tau_k) theta_a, basis = (1, tau, tau^2/2 + g_k)[:terms], weights W_k.

    (ok, omega = theta_1, its covariance, chi^2, chi^2 of the newest residual, alpha = theta_2
    and its covariance (zero when terms == 2)). Compiled: the rate fit runs on every tracked
    frame.
    """
    count = tau.size
    size = 3 * terms
    basis = np.empty((count, terms))
    for k in range(count):
        basis[k, 0] = 1.0
        basis[k, 1] = tau[k]
        if terms == 3:
            basis[k, 2] = 0.5 * tau[k] * tau[k] + gains[k]
    info = np.zeros((size, size))
    rhs = np.zeros(size)
    for k in range(count):
        wphi = weight[k] @ phi[k]
        for a in range(terms):
            for i in range(3):
                rhs[3 * a + i] += basis[k, a] * wphi[i]
                for b in range(terms):
                    for j in range(3):
                        info[3 * a + i, 3 * b + j] += basis[k, a] * basis[k, b] * weight[k, i, j]
    empty = np.zeros((3, 3))
    if abs(np.linalg.det(info)) == 0.0:
        return False, np.zeros(3), empty, 0.0, 0.0, np.zeros(3), np.zeros((3, 3))
    cov_full = np.linalg.inv(info)
    params = cov_full @ rhs
    chi2 = 0.0
    residual = np.zeros(3)
    for k in range(count):
        for i in range(3):
            residual[i] = phi[k, i]
            for a in range(terms):
                residual[i] -= basis[k, a] * params[3 * a + i]
        chi2 += residual @ (weight[k] @ residual)
    newest_chi2 = 0.0
    if 3 * count > size:
        # The newest residual's covariance is P_newest minus the fitted offset's (tau = 0).
        spread = newest_covariance - cov_full[:3, :3]
        if np.linalg.det(spread) > 0.0:
            newest_chi2 = residual @ np.linalg.solve(spread, residual)
    covariance = cov_full[3:6, 3:6]
    alpha = np.zeros(3)
    alpha_cov = np.zeros((3, 3))
    if terms == 3:
        alpha = params[6:9].copy()
        alpha_cov = 0.5 * (cov_full[6:9, 6:9] + cov_full[6:9, 6:9].T)
    return True, params[3:6].copy(), 0.5 * (covariance + covariance.T), chi2, newest_chi2, alpha, alpha_cov
