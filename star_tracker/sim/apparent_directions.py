# SPDX-License-Identifier: Apache-2.0
"""
Apparent directions of sky objects for a moving observer: the renderer's one aberration call site.

Exact relativistic stellar aberration (models.aberration.aberrate, ERFA's eraAb): the apparent
direction leans toward the observer's velocity, by 20.6" at 30 km/s. The Sun's light deflection
(4 mas at 90 deg from the Sun, under 0.02" outside the Sun's exclusion angle) is not applied.
"""
from __future__ import annotations

import numpy as np

from ..models.aberration import SPEED_OF_LIGHT_M_S, aberrate

MAX_SPEED_M_S = 3.0e5  # an observer velocity beyond this is a unit mistake, not a spacecraft


def apparent_directions(vectors: np.ndarray, velocity_m_s) -> np.ndarray:
    """
    Return the apparent unit directions (N, 3) of geometric unit directions `vectors` (N, 3).

    velocity_m_s: the observer's barycentric velocity (3,) [m/s] on ICRS axes (the Earth's
    barycentric velocity plus the spacecraft's orbital one), below MAX_SPEED_M_S. A zero
    velocity returns the directions normalized.
    """
    velocity = np.asarray(velocity_m_s, dtype=float)
    if velocity.shape != (3,) or not np.all(np.isfinite(velocity)) or np.linalg.norm(velocity) >= MAX_SPEED_M_S:
        raise ValueError(f"observer_velocity_m_s={velocity_m_s} must be 3 finite values below "
                         f"{MAX_SPEED_M_S / 1e3:g} km/s")
    if not np.any(velocity):
        return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
    return aberrate(vectors / np.linalg.norm(vectors, axis=1, keepdims=True), velocity)


__all__ = ["SPEED_OF_LIGHT_M_S", "apparent_directions"]
