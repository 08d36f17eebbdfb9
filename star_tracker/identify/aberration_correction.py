# SPDX-License-Identifier: Apache-2.0
"""
The true attitude from one fitted to the catalog's astrometric directions, for a moving observer.

The identifier fits the sensor's rays b_i to the catalog's astrometric directions u_i (R_fit b_i
≈ u_i), but a moving observer sees every star at its apparent direction a_i = aberrate(u_i, v)
(models.aberration: up to ~25" at LEO + the Earth's speed): the true attitude satisfies
R b_i ≈ a_i. Over the matched stars a_i ≈ C u_i, C the rotation of the Wahba fit of u_i onto
a_i; then R = C R_fit. What C leaves (the aberration's differential across the field, ~3" at
the edges of a 15 deg field, a scale-like distortion) has no rotational moment about the stars
the fit used, so composing C is the fit against the apparent directions to far below the
noise (the moment of the fit's residuals times that distortion: ~1e-5"). The covariance, in the
sensor frame, is unchanged.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..models.aberration import aberrate
from ..models.attitude import matrix_to_quaternion
from ..models.attitude_estimation import AttitudeSolution, svd_rotation


def aberration_rotation(star_vectors: np.ndarray, velocity_m_s: np.ndarray) -> np.ndarray:
    """
    Return C (3, 3), the rotation that best carries the stars' astrometric directions onto their apparent ones.

    star_vectors: (M, 3) ICRS unit vectors of the stars the attitude was fitted to (M >= 2);
    velocity_m_s: (3,) the observer's barycentric velocity [m/s], ICRS axes.
    """
    apparent = aberrate(star_vectors, velocity_m_s)
    # svd_rotation(body, ref) maps body onto ref: here the astrometric onto the apparent directions.
    return svd_rotation(star_vectors, apparent)


def corrected_solution(solution: AttitudeSolution, star_vectors: np.ndarray,
                       velocity_m_s: np.ndarray) -> AttitudeSolution:
    """Return `solution` (sensor -> ICRS, fitted to astrometric `star_vectors`) corrected to the true attitude."""
    rotation = aberration_rotation(star_vectors, velocity_m_s) @ solution.rotation
    return replace(solution, rotation=rotation, quaternion=matrix_to_quaternion(rotation))
