# SPDX-License-Identifier: Apache-2.0
"""
The frame conventions of fusion: mountings, alignment corrections and time alignment (mounting.py, time_alignment.py).

Each convention is checked against the truth it claims: a head's rays under the true
mounting, the body attitude a head implies, a star's ray one stamp later.
"""
from __future__ import annotations

import numpy as np
import pytest

from star_tracker.fuse import corrected_mounting, implied_body_attitude, rotation_problem
from star_tracker.fuse.time_alignment import acceleration_covariance, propagate_attitude, propagate_rays
from star_tracker.models.attitude import ARCSEC, rotation_vector_to_matrix

from fuse_spacecraft import MOUNT_A, MOUNT_B, error_vector, random_rotation


@pytest.mark.parametrize("matrix, problem", [
    (np.eye(3)[:2], "shape"),
    (np.full((3, 3), np.nan), "not finite"),
    (np.eye(3) * 1.001, "not orthonormal"),
    (np.diag([1.0, 1.0, -1.0]), "reflection"),
])
def test_a_mounting_that_is_not_a_rotation_is_named(matrix, problem):
    assert problem in rotation_problem(matrix)


def test_rotations_pass_the_check():
    rng = np.random.default_rng(0)
    assert rotation_problem(MOUNT_A) is None and rotation_problem(MOUNT_B) is None
    assert all(rotation_problem(random_rotation(rng)) is None for _ in range(20))


def test_the_heads_of_the_test_spacecraft_point_where_stated():
    # Head B's boresight (+Z) is the body +X axis: v_body = M^T v_head.
    assert np.allclose(MOUNT_B.T @ [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    assert np.allclose(MOUNT_A.T @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0])


def test_a_corrected_mounting_turns_the_head_about_body_axes():
    # c about the body +Y axis turns head B's boresight (body +X) toward body -Z (right-hand rule).
    correction = np.array([0.0, 30.0, 0.0]) * ARCSEC
    boresight_body = corrected_mounting(MOUNT_B, correction).T @ [0.0, 0.0, 1.0]
    assert boresight_body[2] == pytest.approx(-30.0 * ARCSEC, rel=1e-6)


def test_the_implied_body_attitude_undoes_the_true_mounting():
    rng = np.random.default_rng(1)
    body, correction = random_rotation(rng), np.array([4.0, -7.0, 2.0]) * ARCSEC
    mounting = corrected_mounting(MOUNT_B, correction)
    head_covariance = np.diag([1.0, 2.0, 30.0]) * ARCSEC ** 2
    implied, covariance = implied_body_attitude(body @ mounting.T, head_covariance, mounting)
    assert np.max(np.abs(error_vector(implied, body))) < 1e-12
    # The head's roll variance (about its +Z) lands on the body axis the boresight points along.
    assert covariance[0, 0] == pytest.approx(30.0 * ARCSEC ** 2, rel=1e-6)


def test_rays_propagated_with_the_true_rate_are_the_rays_at_the_later_stamp():
    rng = np.random.default_rng(2)
    body, rate, dt = random_rotation(rng), np.radians([0.5, -1.0, 2.0]), 0.08
    stars = rng.normal(size=(5, 3))
    stars /= np.linalg.norm(stars, axis=1, keepdims=True)
    later = propagate_attitude(body, dt, rate)
    assert np.allclose(later, body @ rotation_vector_to_matrix(rate * dt), atol=1e-15)
    assert np.allclose(propagate_rays(stars @ body, dt, rate), stars @ later, atol=1e-14)
    assert np.allclose(propagate_rays(stars @ later, -dt, rate), stars @ body, atol=1e-14)


def test_the_acceleration_term_grows_as_dt_squared():
    one, two = acceleration_covariance(0.05, 0.01), acceleration_covariance(0.1, 0.01)
    assert one[0, 0] == pytest.approx((0.5 * 0.01 * 0.05 ** 2) ** 2 / 3.0)
    assert two[1, 1] == pytest.approx(16.0 * one[1, 1])
    assert np.all(acceleration_covariance(0.1, 0.0) == 0.0)
