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
        self._history: deque[tuple[int, np.ndarray, np.ndarray]] = deque(maxlen=max_frames)  # (ns, R, P^-1)

    def reset(self) -> None:
        self._history.clear()

    def add(self, stamp_ns: int, rotation: np.ndarray, covariance: np.ndarray) -> RateEstimate | None:
        """Add a verified attitude; return the rate at `stamp_ns` once two attitudes are in the
        window, else None. Stamps must increase; an older one restarts the window."""
        if self._history and stamp_ns <= self._history[-1][0]:
            self._history.clear()
        self._history.append((int(stamp_ns), np.asarray(rotation, float), np.linalg.inv(covariance)))
        while self._history and stamp_ns - self._history[0][0] > self.window_ns:
            self._history.popleft()
        return self.estimate()

    def estimate(self) -> RateEstimate | None:
        """The rate at the newest attitude: the longest window (newest frames) whose fit passes
        a chi^2 test at 1 %; a failed test (an acceleration change, a biased attitude) drops
        the oldest attitude and refits, down to two."""
        history = list(self._history)
        while len(history) >= 2:
            fit = _fit(history, self.alpha_max)
            if fit is None:
                return None
            omega, covariance, chi2, dof = fit
            if dof == 0 or chi2 <= _chi2_limit(dof) or len(history) == 2:
                return RateEstimate(history[-1][0], omega, covariance, len(history))
            history = history[1:]
        return None


@lru_cache(maxsize=64)
def _chi2_limit(dof: int) -> float:
    return float(chi2_distribution.ppf(0.99, dof))


def _fit(history, alpha_max: float):
    """GLS fit over `history` [(ns, R, P^-1)]: (omega, covariance, chi^2, dof) or None."""
    newest_ns, newest_rotation, _ = history[-1]
    # With 4+ attitudes the fit includes a constant acceleration, so the rate at the newest
    # frame is unbiased while the body accelerates; with 2-3 it is the constant-rate fit.
    quadratic = len(history) >= 4
    size = 9 if quadratic else 6
    info = np.zeros((size, size))
    rhs = np.zeros(size)
    rows = []
    for stamp_ns, rotation, weight in history:
        # Rotation vector of this attitude relative to the newest, in the newest sensor frame.
        phi = matrix_to_rotation_vector(newest_rotation.T @ rotation)
        tau = (stamp_ns - newest_ns) * 1e-9
        blocks = [np.eye(3), tau * np.eye(3)] + ([0.5 * tau * tau * np.eye(3)] if quadratic else [])
        h = np.hstack(blocks)  # phi = a + omega tau (+ alpha tau^2 / 2)
        info += h.T @ weight @ h
        rhs += h.T @ weight @ phi
        rows.append((h, weight, phi, tau))
    try:
        cov_full = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return None
    params = cov_full @ rhs
    chi2 = float(sum((phi - h @ params) @ weight @ (phi - h @ params) for h, weight, phi, _ in rows))
    dof = 3 * len(history) - size
    covariance = cov_full[3:6, 3:6]
    if not quadratic:
        # Slope bias under acceleration: the rate at the weighted mean time, not the newest.
        weights = np.array([np.trace(w) for _, w, _, _ in rows])
        times = np.array([tau for _, _, _, tau in rows])
        lag = -float(np.sum(weights * times) / np.sum(weights))
        covariance = covariance + np.eye(3) * (alpha_max * lag) ** 2 / 3.0
    return params[3:6], 0.5 * (covariance + covariance.T), chi2, dof
