# SPDX-License-Identifier: Apache-2.0
"""
Bringing an observation made at one stamp to another with the body rate.

Model: over the stamp difference dt = t_to - t_from the body turns at a constant rate omega
(body frame, rad/s): R_body(t_to) = R_body(t_from) exp([omega dt]x). A star fixed in ICRS,
seen along the body-frame ray b(t_from), is seen at t_to along exp(-[omega dt]x) b(t_from).

Error: a rate error d_omega turns all of a frame's rays by d_omega dt, one rotation common
to every head (the same d_omega, each head's own dt); an angular acceleration |alpha| <=
alpha_max leaves up to alpha_max dt^2 / 2 per axis, taken as a uniform error (variance
(alpha_max dt^2 / 2)^2 / 3 per axis) independent from head to head. At 10 Hz frames the
acceleration term is negligible for a few ms of offset; the rate term is not.
"""
from __future__ import annotations

import numpy as np

from ..models.attitude import rotation_vector_to_matrix

NS = 1e-9  # seconds per nanosecond


def stamp_difference_s(to_ns: int, from_ns: int) -> float:
    """Return to_ns - from_ns in seconds (exact integer difference first)."""
    return (int(to_ns) - int(from_ns)) * NS


def propagate_rays(body_rays: np.ndarray, dt_s: float, rate: np.ndarray) -> np.ndarray:
    """Return body-frame unit rays (M, 3) seen dt_s [s] later, the body turning at `rate` [rad/s, body frame]."""
    turn = rotation_vector_to_matrix(np.asarray(rate, dtype=float) * dt_s)
    return np.asarray(body_rays, dtype=float) @ turn  # rows: exp(-[w dt]x) b = turn^T b


def propagate_attitude(body_rotation: np.ndarray, dt_s: float, rate: np.ndarray) -> np.ndarray:
    """Return the body -> ICRS attitude dt_s [s] later: R exp([rate dt]x)."""
    return np.asarray(body_rotation, dtype=float) @ rotation_vector_to_matrix(np.asarray(rate, dtype=float) * dt_s)


def acceleration_covariance(dt_s: float, max_angular_acceleration: float) -> np.ndarray:
    """Return the (3, 3) covariance [rad^2] of the constant-rate model's error over dt_s under |alpha| <= the bound."""
    bound = 0.5 * max_angular_acceleration * dt_s * dt_s
    return np.eye(3) * (bound * bound / 3.0)
