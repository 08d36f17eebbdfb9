# SPDX-License-Identifier: Apache-2.0
"""
The true attitude from one fitted to the catalog's astrometric directions, for a moving observer.

The identifier fits the sensor's rays b_i to the catalog's astrometric directions u_i (R_fit b_i
≈ u_i), but a moving observer sees every star at its apparent direction a_i = aberrate(u_i, v)
(models.aberration: up to ~25" at LEO + the Earth's speed): the true attitude satisfies
R b_i ≈ a_i. Over the matched stars a_i ≈ C u_i, C the rotation of the Wahba fit of u_i onto
a_i; then R = C R_fit. What C leaves is the aberration's differential across the field (~3" at
the edges of a 15 deg field): a scale of ~|v|/c about the boresight. With the stars weighted
equally it has no rotational moment that C does not remove, so composing C is the fit against
the apparent directions to far below the noise (~1e-5"). The identifier weights each star by
its own covariance, though, and that scale's moment under those weights differs from C's by up
to ~|v|/c times the offset of the weights' centre from the stars' (~1" when a bright, precisely
measured star sits off the centre of the field). Given the rays and covariances the fit used,
corrected_solution therefore refits against the apparent directions with them (exact); without,
it composes C (covariance unchanged, in the sensor frame).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..models.aberration import aberrate
from ..models.attitude import matrix_to_quaternion
from ..models.attitude_estimation import AttitudeSolution, refine_with_covariances, svd_rotation
from .base import FIT_SCREEN_CHI2
from .verify import MIN_STARS


def aberration_rotation(star_vectors: np.ndarray, velocity_m_s: np.ndarray) -> np.ndarray:
    """
    Return C (3, 3), the rotation that best carries the stars' astrometric directions onto their apparent ones.

    star_vectors: (M, 3) ICRS unit vectors of the stars the attitude was fitted to (M >= 2);
    velocity_m_s: (3,) the observer's barycentric velocity [m/s], ICRS axes.
    """
    apparent = aberrate(star_vectors, velocity_m_s)
    # svd_rotation(body, ref) maps body onto ref: here the astrometric onto the apparent directions.
    return svd_rotation(star_vectors, apparent)


def corrected_solution(solution: AttitudeSolution, star_vectors: np.ndarray, velocity_m_s: np.ndarray,
                       body_vectors: np.ndarray | None = None, ray_cov: np.ndarray | None = None) -> AttitudeSolution:
    """
    Return `solution` (sensor -> ICRS, fitted to astrometric `star_vectors`) corrected to the true attitude.

    body_vectors (M, 3), ray_cov (M, 3, 3) [rad^2]: the matched stars' sensor-frame rays and their
    covariances as the fit weighted them (the identifier's: Identification.body_vectors and
    identify.base.direction_covariance of the matched spots). Given, the attitude is refitted
    against the apparent directions with those weights from C R (refine_with_covariances, stars
    beyond FIT_SCREEN_CHI2 under their residual's covariance left out once, as the identifier's own fit), its
    covariance the refit's; without, C R (module docstring).
    """
    rotation = aberration_rotation(star_vectors, velocity_m_s) @ solution.rotation
    if body_vectors is None or ray_cov is None:
        return replace(solution, rotation=rotation, quaternion=matrix_to_quaternion(rotation))
    apparent = aberrate(star_vectors, velocity_m_s)
    refit, chi2, _ = refine_with_covariances(rotation, body_vectors, apparent, ray_cov)
    inlier = chi2 <= FIT_SCREEN_CHI2
    if not inlier.all() and inlier.sum() >= MIN_STARS:
        refit, _, _ = refine_with_covariances(refit.rotation, body_vectors, apparent, ray_cov, used=inlier)
    return refit
