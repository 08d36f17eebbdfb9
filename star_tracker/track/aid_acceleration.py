# SPDX-License-Identifier: Apache-2.0
"""
The angular acceleration a rate-aided centroider may use: only one its samples show.

A smear model with an acceleration alpha moves every point-like spot by alpha T^2 / 24 of the
rotation (and bends the streaks' predicted paths): right when the body accelerates, a bias
when alpha is an artefact of the samples. The slope of a line through a gyro's last samples is
one whenever the rate does not change linearly: under 20" of jitter at 20 Hz, 0.25 s of
samples gave a slope of 0.34 deg/s^2 and moved the spots by 0.5-0.8" with the frames' NEES at
18-26 (stress campaign probe; 1-2 without it). So an acceleration is used only when it is
significant against its own uncertainty: alpha^T C^-1 alpha >= SIGNIFICANT_CHI2 (chi^2_3's 1 %
tail), C the fit's covariance (a line through samples: from their scatter about it, which
jitter makes large; the identifier's estimate: RateEstimate.acceleration_covariance). A body
at rest or at a constant rate then gets none, which is what it needs.
"""
from __future__ import annotations

import numpy as np

SIGNIFICANT_CHI2 = 11.344866730144373  # scipy.stats.chi2.ppf(0.99, 3)
MIN_SAMPLES = 3  # a line through fewer leaves no scatter to judge its slope by


def significant(alpha: np.ndarray | None, covariance: np.ndarray | None) -> np.ndarray | None:
    """Return alpha [rad/s^2] when alpha^T C^-1 alpha >= SIGNIFICANT_CHI2 under its covariance C, else None."""
    if alpha is None or covariance is None:
        return None
    alpha = np.asarray(alpha, float).reshape(3)
    covariance = np.asarray(covariance, float).reshape(3, 3)
    if not (np.all(np.isfinite(alpha)) and np.all(np.isfinite(covariance))):
        return None
    try:
        chi2 = float(alpha @ np.linalg.solve(covariance, alpha))
    except np.linalg.LinAlgError:
        return None
    return alpha if chi2 >= SIGNIFICANT_CHI2 else None


def from_samples(offsets_s: np.ndarray, rates: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """
    Return (alpha [rad/s^2], its covariance [rad^2/s^4]) of a line through rate samples, or (None, None).

    offsets_s (n,) [s]: the samples' times (any origin); rates (n, 3) [rad/s]. The covariance is
    the slope's from the samples' scatter about the line (per axis, independent); fewer than
    MIN_SAMPLES or a zero time span give none.
    """
    t = np.asarray(offsets_s, float).ravel()
    w = np.asarray(rates, float).reshape(-1, 3)
    if t.size < MIN_SAMPLES or t.size != w.shape[0]:
        return None, None
    t = t - t.mean()
    spread = float(t @ t)
    if not spread > 0:
        return None, None
    slope = (t @ (w - w.mean(axis=0))) / spread
    residual = w - w.mean(axis=0) - np.outer(t, slope)
    variance = np.sum(residual ** 2, axis=0) / (t.size - 2) / spread
    return slope, np.diag(np.maximum(variance, np.finfo(float).tiny))
