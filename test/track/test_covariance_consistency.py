# SPDX-License-Identifier: Apache-2.0
"""
The published attitude covariance against the simulator's truth (issue 6).

Render -> extract_spots -> hybrid identify with default settings, NEES of the attitude error
under the published covariance. The full benchmark (bench/bench_attitude.py) runs >= 1000
frames; this is its small, fast cousin with bands wide enough for 150 frames.
"""
from __future__ import annotations

import numpy as np
import pytest

from star_tracker.models.attitude import matrix_to_rotation_vector, quaternion_to_matrix, radec_roll_to_matrix
from star_tracker.centroid import FLAG_SATURATED, CentroidConfig, extract_spots
from star_tracker.identify import IdentifyConfig, make_identifier
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel

CHI2_3_999 = 16.27  # P(chi^2_3 > 16.27) = 0.001


@pytest.fixture(scope="module")
def chain(catalog, database, nominal_camera):
    renderer = StarFieldRenderer(nominal_camera, SensorModel(), catalog.at_epoch(database.config.epoch_jyear),
                                 magnitude_limit=7.5)
    identifier = make_identifier("hybrid", database, IdentifyConfig())
    identifier.warm_up(nominal_camera)
    return renderer, identifier, nominal_camera


def attitude_nees(chain, rotation, seed):
    """(3-DOF NEES, x/y NEES, roll NEES, the frame's spots) of one frame at rest, or None."""
    renderer, identifier, camera = chain
    frame = renderer.render(ConstantRateMotion(rotation, np.zeros(3)), 0.0, seed)
    spots = extract_spots(frame.image, CentroidConfig())
    result = identifier.identify(spots, camera)
    if not result.solved:
        return None
    d = matrix_to_rotation_vector(frame.truth.rotation.T @ result.attitude.rotation)
    p = result.attitude.covariance
    return (float(d @ np.linalg.solve(p, d)), float(d[:2] @ np.linalg.solve(p[:2, :2], d[:2])),
            float(d[2] ** 2 / p[2, 2]), spots, result)


@pytest.mark.slow  # ~8 s
def test_published_covariance_is_consistent_at_rest(chain):
    # 150 random attitudes: the mean NEES of an honest covariance is 3 (x/y 2, roll 1) with a
    # standard error of sqrt(6 / 150) = 0.2; the bands are 3 standard errors. The identifier's
    # sigma floor (NEES ~1) or an unflagged clipped star (NEES ~70 in its frame) fails them.
    rng = np.random.default_rng(6)
    values = []
    for k in range(150):
        out = attitude_nees(chain, quaternion_to_matrix(rng.normal(size=4)), frame_seed(66, k))
        assert out is not None
        values.append(out[:3])
    nees = np.array(values)
    assert 2.4 < nees[:, 0].mean() < 3.6
    assert 1.5 < nees[:, 1].mean() < 2.5
    assert 0.65 < nees[:, 2].mean() < 1.35
    assert np.sum(nees[:, 0] > CHI2_3_999) <= 2  # expected 0.15 frames


def test_a_clipped_bright_star_is_flagged_and_does_not_spoil_the_attitude(chain, catalog, database):
    # Default CentroidConfig (saturation_adu = 0: the uint16 maximum), but the simulated sensor
    # clips at full well 60000 e- + bias = 60100 ADU: the flat top must give the star away, and
    # its centroid, fitted without the clipped pixels, must keep the covariance honest. The five
    # brightest stars the database holds (alpha Cen, a close pair, is not one of them).
    in_database = np.isin(catalog.hip, database.hip)
    brightest = [i for i in np.argsort(catalog.hp)[:20] if in_database[i]][:5]
    values = []
    for k, star in enumerate(brightest):
        rotation = radec_roll_to_matrix(catalog.ra[star] + 0.02 / np.cos(catalog.dec[star]), catalog.dec[star] - 0.03,
                                        0.5 * k)
        nees, _, _, spots, result = attitude_nees(chain, rotation, frame_seed(67, k))
        flagged = (spots.flags & FLAG_SATURATED) != 0
        assert flagged.any() and np.all(spots.peak[flagged] > 40000.0)
        assert np.isin(np.flatnonzero(flagged), result.spot_index).any()  # and used by the attitude
        values.append(nees)
    assert max(values) < CHI2_3_999


def test_direction_sigma_follows_the_camera_model(nominal_camera):
    # sqrt(trace(J C J^T) / 2) with J = d ray / d pixel: the analytic pinhole Jacobian against
    # central differences, and the foreshortening toward the corner (cos^2 and cos of the field
    # angle across and along the radius) that a single pixel scale misses.
    from dataclasses import replace

    from star_tracker.identify.base import direction_sigma

    rng = np.random.default_rng(8)
    x, y = rng.uniform(0, 1023, 50), rng.uniform(0, 1023, 50)
    a = rng.normal(size=(50, 2, 2)) * 0.05
    cov = a @ np.transpose(a, (0, 2, 1)) + 1e-4 * np.eye(2)
    analytic = direction_sigma(nominal_camera, x, y, cov)
    h = 1e-3
    jx = (nominal_camera.pixel_to_ray(x + h, y) - nominal_camera.pixel_to_ray(x - h, y)) / (2 * h)
    jy = (nominal_camera.pixel_to_ray(x, y + h) - nominal_camera.pixel_to_ray(x, y - h)) / (2 * h)
    jac = np.stack([jx, jy], axis=2)  # (N, 3, 2)
    numeric = np.sqrt(0.5 * np.einsum("nij,njk,nik->n", jac, cov, jac))
    assert np.allclose(analytic, numeric, rtol=1e-6)
    corner = direction_sigma(nominal_camera, np.array([0.0]), np.array([0.0]), np.eye(2)[None] * 0.01)[0]
    centre = direction_sigma(nominal_camera, np.array([nominal_camera.cx]), np.array([nominal_camera.cy]),
                             np.eye(2)[None] * 0.01)[0]
    field = nominal_camera.half_diagonal_fov_rad
    assert corner / centre == pytest.approx(np.sqrt(0.5 * (np.cos(field) ** 4 + np.cos(field) ** 2)), rel=1e-3)
    # A distorted camera takes the numeric path; with a negligible distortion it agrees.
    distorted = replace(nominal_camera, distortion=(1e-9, 0.0, 0.0, 0.0, 0.0))
    assert np.allclose(direction_sigma(distorted, x, y, cov), analytic, rtol=1e-4)
