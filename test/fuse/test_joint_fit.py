# SPDX-License-Identifier: Apache-2.0
"""
The joint fit over several heads' stars (fuse/joint_fit.py) against its model's exact answers.

One head without common errors is QUEST with Shuster & Oh's covariance; an error common to
one head's rays is averaged down by a second head, an error shared by both (the rate error
times one stamp offset) is not; a wrong start converges.
"""
from __future__ import annotations

import numpy as np
import pytest

from star_tracker.fuse import HeadRays, fit_heads
from star_tracker.models.attitude import ARCSEC, rotation_vector_to_matrix
from star_tracker.models.attitude_estimation import attitude_covariance, quest

from fuse_spacecraft import MOUNT_A, MOUNT_B, error_vector, noisy_rays, random_rotation


def field_rays(rng, mounting, count=40, half_angle=0.12):
    """Return body-frame unit rays of `count` stars spread over a head's field (boresight along mounting's +Z)."""
    head = np.column_stack([rng.uniform(-half_angle, half_angle, (count, 2)), np.ones(count)])
    head /= np.linalg.norm(head, axis=1, keepdims=True)
    return head @ mounting  # rows M^T v


def head_rays(name, body_rays, body, sigma, rng, own=None, shared_map=None):
    """Return HeadRays of exact catalog vectors for `body` (body -> ICRS) and noisy measured rays."""
    sigmas = np.full(len(body_rays), sigma)
    return HeadRays(name, noisy_rays(body_rays, sigmas, rng), body_rays @ body.T, sigmas,
                    np.zeros((3, 3)) if own is None else own, np.zeros((3, 0)) if shared_map is None else shared_map)


def test_one_head_without_common_errors_is_quest():
    rng = np.random.default_rng(10)
    body = random_rotation(rng)
    head = head_rays("a", field_rays(rng, MOUNT_A), body, 2.0 * ARCSEC, rng)
    fit = fit_heads([head])
    reference = quest(head.body_rays, head.catalog_vectors, head.sigmas)
    assert np.max(np.abs(error_vector(fit.rotation, reference.rotation))) < 1e-11
    assert np.allclose(fit.covariance, attitude_covariance(head.body_rays, head.sigmas), rtol=1e-6)
    assert fit.residuals["a"].stars == 40
    assert np.linalg.norm(fit.residuals["a"].offset) < 1e-9  # the head alone agrees with itself


def test_a_start_far_off_converges_to_the_same_optimum():
    rng = np.random.default_rng(11)
    body = random_rotation(rng)
    heads = [head_rays("a", field_rays(rng, MOUNT_A), body, 2.0 * ARCSEC, rng, own=np.eye(3) * (3 * ARCSEC) ** 2),
             head_rays("b", field_rays(rng, MOUNT_B), body, 2.0 * ARCSEC, rng, own=np.eye(3) * (1 * ARCSEC) ** 2)]
    many = fit_heads(heads, iterations=8)
    few = fit_heads(heads, iterations=2)
    assert np.max(np.abs(error_vector(few.rotation, many.rotation))) < 1e-4 * ARCSEC


def test_an_error_of_one_head_alone_is_averaged_down_by_the_other():
    """Each head's rays share a 5 arcsec error of their own; stars are near perfect: the fused variance is half."""
    rng = np.random.default_rng(12)
    body, own = random_rotation(rng), np.eye(3) * (5.0 * ARCSEC) ** 2
    heads = [head_rays(n, field_rays(rng, MOUNT_A), body, 1e-3 * ARCSEC, rng, own=own) for n in ("a", "b")]
    assert np.allclose(fit_heads(heads[:1]).covariance, own, rtol=1e-3)
    assert np.allclose(fit_heads(heads).covariance, own / 2.0, rtol=1e-3)


def test_an_error_shared_by_the_heads_is_not_averaged_away():
    """Both heads 60 ms before the stamp, a rate error of 20 urad/s: 1.2 urad common to all rays, whatever the heads."""
    rng = np.random.default_rng(13)
    body, dt, rate_covariance = random_rotation(rng), 0.06, np.eye(3) * 20e-6 ** 2
    shared_map = np.eye(3) * dt
    heads = [head_rays("a", field_rays(rng, MOUNT_A), body, 1e-3 * ARCSEC, rng, shared_map=shared_map),
             head_rays("b", field_rays(rng, MOUNT_B), body, 1e-3 * ARCSEC, rng, shared_map=shared_map)]
    assert np.allclose(fit_heads(heads, rate_covariance).covariance, dt ** 2 * rate_covariance, rtol=1e-3)


def test_a_common_rotation_of_one_head_shows_in_its_residual_offset():
    """Head b's rays turned by 8 arcsec about body Y: its offset says so, head a's is near zero."""
    rng = np.random.default_rng(14)
    body, turn = random_rotation(rng), np.array([0.0, 8.0, 0.0]) * ARCSEC
    a = head_rays("a", field_rays(rng, MOUNT_A), body, 0.5 * ARCSEC, rng)
    b = head_rays("b", field_rays(rng, MOUNT_B), body @ rotation_vector_to_matrix(turn), 0.5 * ARCSEC, rng)
    fit = fit_heads([a, b])
    offset_a, offset_b = fit.residuals["a"].offset, fit.residuals["b"].offset
    assert offset_b[1] - offset_a[1] == pytest.approx(8.0 * ARCSEC, abs=0.5 * ARCSEC)
    assert fit.chi2 > 2 * 80 + 5 * np.sqrt(4 * 80)  # far above its 2 DOF per star


def test_no_head_or_a_degenerate_set_is_an_error():
    with pytest.raises(ValueError, match="no head"):
        fit_heads([])
    ray = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ValueError):
        fit_heads([HeadRays("a", ray, ray, np.full(2, 1e-5), np.zeros((3, 3)), np.zeros((3, 0)))])
