# SPDX-License-Identifier: Apache-2.0
"""
Apparent directions of sky objects for a moving observer: the renderer's one aberration call site.

First-order stellar aberration, u' = (u + beta) / |u + beta| with beta = v / c: the
apparent direction tilts toward the observer's velocity (20.6" at 30 km/s; terms of order
beta^2, <= 2 mas at 30 km/s, neglected). The relativistic model is meant to replace the
formula here, in this one function, so every caller gets it at once.
"""
from __future__ import annotations

import numpy as np

SPEED_OF_LIGHT_M_S = 299_792_458.0


def apparent_directions(vectors: np.ndarray, velocity_m_s) -> np.ndarray:
    """
    Return the apparent unit directions (N, 3) of geometric unit directions `vectors` (N, 3).

    velocity_m_s: the observer's velocity (3,) [m/s] in the same axes (ICRS/GCRS: the
    Earth's barycentric velocity plus the spacecraft's orbital one), below ~300 km/s (|beta| < 1e-3).
    """
    beta = np.asarray(velocity_m_s, dtype=float) / SPEED_OF_LIGHT_M_S
    if beta.shape != (3,) or not np.all(np.isfinite(beta)) or np.linalg.norm(beta) >= 1e-3:
        raise ValueError(f"observer_velocity_m_s={velocity_m_s} must be 3 finite values below 300 km/s")
    vectors = vectors + beta
    return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
