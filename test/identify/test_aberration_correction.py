# SPDX-License-Identifier: Apache-2.0
"""
The identifier's attitude corrected for the observer's velocity (identify/aberration_correction.py).

Frames rendered for an observer at LEO + the Earth's speed (the renderer draws every star at its
exact relativistic apparent place, checked against ERFA in test/sim), centroided and identified
against the astrometric catalog: uncorrected, the attitude is off by the aberration (~30" here);
corrected with the velocity, its error is that of the same frames rendered for an observer at
rest. The composition C R equals a direct refit against the apparent directions.
"""
from __future__ import annotations

import numpy as np

from star_tracker.centroid import extract_spots
from star_tracker.identify import make_identifier
from star_tracker.identify.aberration_correction import aberration_rotation, corrected_solution
from star_tracker.models.aberration import aberrate
from star_tracker.models.attitude import attitude_error, radec_roll_to_matrix
from star_tracker.models.attitude_estimation import svd_rotation
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel

ARCSEC = np.radians(1.0 / 3600.0)
VELOCITY = np.array([-29_800.0, 7_600.0, 2_100.0])  # [m/s] ICRS: the Earth's barycentric + an orbit's


def solve(catalog, database, camera, velocity, seed):
    truth = radec_roll_to_matrix(np.radians(40.0 + 25 * seed), np.radians(-20.0 + 9 * seed), 0.3 * seed)
    renderer = StarFieldRenderer(camera, SensorModel(), catalog, 7.5, observer_velocity_m_s=velocity)
    frame = renderer.render(ConstantRateMotion(truth, np.zeros(3)), 1.0, frame_seed(5, seed))
    result = make_identifier("hybrid", database).identify(extract_spots(frame.image), camera)
    assert result.solved
    return result, frame.truth.rotation


def total_error(rotation, truth) -> float:
    return float(attitude_error(rotation, truth)[2])


def test_the_corrected_attitude_is_as_good_as_at_rest(catalog, database, nominal_camera):
    at_rest, uncorrected, corrected = [], [], []
    for seed in range(4):
        result, truth = solve(catalog, database, nominal_camera, np.zeros(3), seed)
        at_rest.append(total_error(result.attitude.rotation, truth))
        moving, truth = solve(catalog, database, nominal_camera, VELOCITY, seed)
        uncorrected.append(total_error(moving.attitude.rotation, truth))
        fixed = corrected_solution(moving.attitude, moving.star_vectors, VELOCITY)
        corrected.append(total_error(fixed.rotation, truth))
        assert np.array_equal(fixed.covariance, moving.attitude.covariance)
    # The aberration: beta sin(theta), 31" for this velocity across the boresight.
    assert min(uncorrected) > 15 * ARCSEC
    assert max(corrected) < 3 * ARCSEC
    assert np.sqrt(np.mean(np.square(corrected))) < 1.5 * np.sqrt(np.mean(np.square(at_rest))) + 0.2 * ARCSEC


def test_composing_the_correction_is_a_refit_against_the_apparent_directions(catalog):
    rng = np.random.default_rng(3)
    truth = radec_roll_to_matrix(np.radians(120.0), np.radians(30.0), 1.0)
    stars = catalog.brighter_than(6.0).unit_vectors()
    stars = stars[stars @ truth[:, 2] > np.cos(np.radians(7.5))]
    rays = (truth.T @ aberrate(stars, VELOCITY).T).T + rng.normal(0.0, 2 * ARCSEC, stars.shape)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    fitted = svd_rotation(rays, stars)  # against the astrometric catalog
    direct = svd_rotation(rays, aberrate(stars, VELOCITY))
    composed = aberration_rotation(stars, VELOCITY) @ fitted
    assert total_error(composed, direct) < 1e-3 * ARCSEC
    assert total_error(fitted, direct) > 15 * ARCSEC


def test_with_the_fits_weights_the_correction_is_a_refit_when_one_star_outweighs_the_rest(catalog):
    """
    A fit weighted by each star's covariance: one bright star off the centre measured 50x better than the rest.

    Composing C (unweighted) leaves the aberration's scale about the boresight weighted differently
    from the fit: 1.6" here; given the rays and their covariances the correction is the weighted
    refit against the apparent directions (noise-free: the truth).
    """
    from star_tracker.models.attitude_estimation import refine_with_covariances

    truth = radec_roll_to_matrix(np.radians(200.0), np.radians(-10.0), 0.4)
    stars = catalog.brighter_than(6.0).unit_vectors()
    stars = stars[stars @ truth[:, 2] > np.cos(np.radians(7.5))]
    rays = (truth.T @ aberrate(stars, VELOCITY).T).T  # exact: the error is the correction's alone
    sigma = np.full(len(stars), 2 * ARCSEC)
    sigma[np.argmin(rays[:, 2])] = 0.04 * ARCSEC  # the star farthest from the boresight
    ray_cov = sigma[:, None, None] ** 2 * (np.eye(3)[None] - rays[:, :, None] * rays[:, None, :])
    fitted, _, _ = refine_with_covariances(svd_rotation(rays, stars), rays, stars, ray_cov)  # as the identifier
    composed = corrected_solution(fitted, stars, VELOCITY)
    refitted = corrected_solution(fitted, stars, VELOCITY, rays, ray_cov)
    assert total_error(composed.rotation, truth) > 0.3 * ARCSEC
    assert total_error(refitted.rotation, truth) < 1e-3 * ARCSEC
    assert np.allclose(refitted.covariance, fitted.covariance, rtol=1e-3)
