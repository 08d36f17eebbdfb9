"""Body angular velocity from successive attitudes (and, when stars are smeared, from streaks).

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
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit
from scipy.stats import chi2 as chi2_distribution

from .attitude import matrix_to_rotation_vector


@dataclass(frozen=True)
class RateEstimate:
    """angular_velocity: (3,) body rate in the sensor frame [rad/s] at `stamp_ns`;
    covariance: (3, 3) [rad^2/s^2]; frames: attitudes used."""

    stamp_ns: int
    angular_velocity: np.ndarray
    covariance: np.ndarray
    frames: int

    @property
    def sigma(self) -> np.ndarray:
        """(3,) 1-sigma per sensor axis [rad/s]."""
        return np.sqrt(np.diag(self.covariance))


class AttitudeRateEstimator:
    """Sliding-window rate estimate from verified attitudes (oldest dropped after `window_s`)."""

    def __init__(self, window_s: float = 0.35, max_angular_acceleration_rad_s2: float = np.radians(1.0),
                 max_frames: int = 8):
        if not (window_s > 0 and max_angular_acceleration_rad_s2 >= 0 and max_frames >= 2):
            raise ValueError(f"invalid rate estimator settings: window_s={window_s}, "
                             f"max_angular_acceleration_rad_s2={max_angular_acceleration_rad_s2}, max_frames={max_frames}")
        self.window_ns = int(window_s * 1e9)
        self.alpha_max = float(max_angular_acceleration_rad_s2)
        self._history: deque[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = deque(maxlen=max_frames)  # (ns, R, P^-1, P)

    def reset(self) -> None:
        self._history.clear()

    def add(self, stamp_ns: int, rotation: np.ndarray, covariance: np.ndarray) -> RateEstimate | None:
        """Add a verified attitude; return the rate at `stamp_ns` once two attitudes are in the
        window, else None. Stamps must increase; an older one restarts the window."""
        if self._history and stamp_ns <= self._history[-1][0]:
            self._history.clear()
        covariance = np.asarray(covariance, float)
        try:
            information = np.linalg.inv(covariance)
        except np.linalg.LinAlgError:
            raise ValueError("attitude covariance must be invertible") from None
        self._history.append((int(stamp_ns), np.asarray(rotation, float), information, covariance))
        while self._history and stamp_ns - self._history[0][0] > self.window_ns:
            self._history.popleft()
        return self.estimate()

    def estimate(self) -> RateEstimate | None:
        """The rate at the newest attitude: the longest window (newest frames) whose fit passes
        two chi^2 tests at 1 % (all residuals; the newest attitude's own residual, which an
        acceleration change since the previous frame shows first); a failed test drops the
        oldest attitude and refits, down to two."""
        if len(self._history) < 2:
            return None
        stamps = np.array([h[0] for h in self._history], np.int64)
        rotations = np.array([h[1] for h in self._history])
        weights = np.array([h[2] for h in self._history])
        newest_covariance = self._history[-1][3]
        # Rotation vectors relative to the newest attitude, in the newest sensor frame.
        phi = _small_rotation_vectors(np.einsum("ji,kjl->kil", rotations[-1], rotations))
        tau = (stamps - stamps[-1]) * 1e-9
        first = 0
        while stamps.size - first >= 2:
            fit = _fit(tau[first:], phi[first:], weights[first:], newest_covariance, self.alpha_max)
            if fit is None:
                return None
            omega, covariance, chi2, dof, newest_chi2 = fit
            passed = (dof == 0 or chi2 <= _chi2_limit(dof)) and newest_chi2 <= _chi2_limit(3)
            if passed or stamps.size - first == 2:
                return RateEstimate(int(stamps[-1]), omega, covariance, int(stamps.size - first))
            first += 1
        return None


@lru_cache(maxsize=64)
def _chi2_limit(dof: int) -> float:
    return float(chi2_distribution.ppf(0.99, dof))


def _small_rotation_vectors(rotations: np.ndarray) -> np.ndarray:
    """(k, 3) rotation vectors of (k, 3, 3) rotations from their antisymmetric part (exact
    for angles below pi/2, which a rate window never approaches; larger ones fall back)."""
    axis_sin = 0.5 * np.stack([rotations[:, 2, 1] - rotations[:, 1, 2], rotations[:, 0, 2] - rotations[:, 2, 0],
                               rotations[:, 1, 0] - rotations[:, 0, 1]], axis=1)
    cos = 0.5 * (np.trace(rotations, axis1=1, axis2=2) - 1.0)
    if np.any(cos < 0.0):
        return np.array([matrix_to_rotation_vector(r) for r in rotations])
    sin = np.linalg.norm(axis_sin, axis=1)
    angle = np.arctan2(sin, cos)
    scale = np.where(sin > 1e-12, angle / np.where(sin > 1e-12, sin, 1.0), 1.0)
    return axis_sin * scale[:, None]


def _fit(tau: np.ndarray, phi: np.ndarray, weight: np.ndarray, newest_covariance: np.ndarray, alpha_max: float):
    """GLS fit of phi(tau) [rad] at times tau [s] (newest last, tau = 0) with weights P^-1:
    (omega, covariance, chi^2, dof, chi^2 of the newest attitude's residual) or None."""
    # With 4+ attitudes the fit includes a constant acceleration, so the rate at the newest
    # frame is unbiased while the body accelerates; with 2-3 it is the constant-rate fit.
    terms = 3 if tau.size >= 4 else 2
    ok, omega, covariance, chi2, newest_chi2 = _gls(np.ascontiguousarray(tau), np.ascontiguousarray(phi),
                                                    np.ascontiguousarray(weight), np.ascontiguousarray(newest_covariance),
                                                    terms)
    if not ok:
        return None
    if terms == 2:
        # Slope bias under acceleration: the rate at the weighted mean time, not the newest.
        trace = np.trace(weight, axis1=1, axis2=2)
        lag = -float(np.sum(trace * tau) / np.sum(trace))
        covariance = covariance + np.eye(3) * (alpha_max * lag) ** 2 / 3.0
    return omega, covariance, chi2, 3 * tau.size - 3 * terms, newest_chi2


@njit(cache=True)
def _gls(tau, phi, weight, newest_covariance, terms):
    """phi_k = sum_a basis_a(tau_k) theta_a, basis = (1, tau, tau^2/2)[:terms], weights W_k:
    (ok, omega = theta_1, its covariance, chi^2, chi^2 of the newest residual). Compiled: the
    rate fit runs on every tracked frame."""
    count = tau.size
    size = 3 * terms
    basis = np.empty((count, terms))
    for k in range(count):
        basis[k, 0] = 1.0
        basis[k, 1] = tau[k]
        if terms == 3:
            basis[k, 2] = 0.5 * tau[k] * tau[k]
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
        return False, np.zeros(3), empty, 0.0, 0.0
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
    return True, params[3:6].copy(), 0.5 * (covariance + covariance.T), chi2, newest_chi2
