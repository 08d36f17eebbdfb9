"""Spacecraft attitude motion profiles.

An attitude is the sensor -> ICRS rotation matrix R (v_icrs = R v_sensor). Body rates are
expressed in the sensor frame [rad/s]. Times are seconds on the node's clock.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .attitude import rotation_vector_to_matrix


@dataclass(frozen=True)
class ConstantRateMotion:
    """R(t) = R0 exp([omega x] (t - t0)): a fixed attitude when omega = 0.

    initial_rotation: R0 at time t0 [s]; body_rate: omega in the sensor frame [rad/s].
    """

    initial_rotation: np.ndarray
    body_rate: np.ndarray
    t0: float = 0.0

    def rotation_at(self, t: float) -> np.ndarray:
        return self.initial_rotation @ rotation_vector_to_matrix(np.asarray(self.body_rate) * (t - self.t0))

    def rotations_at(self, times: np.ndarray) -> np.ndarray:
        """Stacked rotations (K, 3, 3) at each time (vectorized Rodrigues)."""
        dt = np.asarray(times, dtype=float) - self.t0
        rate = np.asarray(self.body_rate, dtype=float)
        speed = float(np.linalg.norm(rate))
        if speed == 0.0:
            return np.broadcast_to(self.initial_rotation, (dt.size, 3, 3)).copy()
        axis = rate / speed
        k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
        angles = speed * dt
        step = (np.eye(3)[None] + np.sin(angles)[:, None, None] * k[None]
                + (1.0 - np.cos(angles))[:, None, None] * (k @ k)[None])
        return self.initial_rotation[None] @ step

    def angular_velocity_at(self, t: float) -> np.ndarray:
        return np.asarray(self.body_rate, dtype=float).copy()
