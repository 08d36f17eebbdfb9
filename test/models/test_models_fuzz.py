# SPDX-License-Identifier: Apache-2.0
"""
Property-based tests (hypothesis) of the shared models on arbitrary numbers.

Camera models (star_tracker.models.camera) and the attitude solvers and rotation conversions
(star_tracker.models.attitude). A valid result, or ValueError with a message; never another
exception. Defects found by fuzzing are pinned at the end, each with its failing input
(docs/RELIABILITY.md, "Defects found by fuzzing in the core").
"""
from __future__ import annotations

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

from star_tracker.models.attitude import (attitude_error, matrix_to_quaternion, quaternion_to_matrix,  # noqa: E402
                                          rotation_vector_to_matrix)
from star_tracker.models.attitude_estimation import davenport_q_method, quest, svd_attitude  # noqa: E402
from star_tracker.models.camera import CameraModel  # noqa: E402

from fuzz_support import CAMERAS, examples, is_rotation, refused, some_float, valid_or_value_error  # noqa: E402


# ============================================================================ camera
@examples(800)
@given(st.one_of(st.integers(-5, 5000), st.integers(-2**40, 2**40)), st.integers(-5, 5000),
       some_float, some_float, some_float, some_float,
       st.one_of(st.lists(st.floats(-0.3, 0.3), min_size=5, max_size=5), st.lists(some_float, max_size=7)))
def test_camera_model_is_valid_or_refused(width, height, fx, fy, cx, cy, distortion):
    camera = valid_or_value_error(CameraModel, width, height, fx, fy, cx, cy, tuple(distortion))
    if camera is None:
        return
    assert camera.width > 0 and camera.height > 0 and camera.fx > 0 and np.isfinite(camera.fy)
    u = np.array([0.0, camera.cx, camera.width - 1.0])
    rays = camera.pixel_to_ray(u, u)
    assert rays.shape == (3, 3)


# ============================================================================ attitude
# Directions: any non-zero finite vector (parallel, antiparallel, duplicated), or NaN/inf.
# Zero vectors and vectors whose norm overflows: test_zero_or_overflowing_vectors_are_refused.
direction = st.one_of(
    st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3).filter(lambda v: 1e-6 < np.linalg.norm(v)),
    st.sampled_from([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1e-3, 0.0, 1.0], [np.nan, 0.0, 1.0], [0.0, np.inf, 1.0]]))
sigma_values = st.one_of(st.floats(1e-6, 1.0), st.sampled_from([0.0, -1.0, np.nan, -np.inf]))


@examples(800)
@given(st.lists(direction, max_size=6), st.data(), st.sampled_from([quest, davenport_q_method, svd_attitude]))
@pytest.mark.slow  # ~5 s
def test_attitude_solvers_on_degenerate_inputs(body, data, solver):
    """
    A proper rotation or ValueError.

    Two or more finite vectors with positive sigmas (parallel, antiparallel or duplicated
    included): always a rotation. NaN, infinities, zero or negative sigmas, fewer than two
    pairs: refused (never a NaN attitude).
    """
    n = len(body)
    ref = data.draw(st.one_of(st.just(body), st.lists(direction, min_size=n, max_size=n)))
    sigmas = np.asarray(data.draw(st.one_of(st.just(1e-4), st.lists(sigma_values, min_size=n, max_size=n))), float)
    body_a, ref_a = np.array(body, float).reshape(-1, 3), np.array(ref, float).reshape(-1, 3)
    with np.errstate(all="ignore"):
        solution = valid_or_value_error(solver, body_a, ref_a, sigmas)
    clean = n >= 2 and np.all(np.isfinite(body_a)) and np.all(np.isfinite(ref_a)) and np.all(sigmas > 0)
    assert (solution is not None) == bool(clean)
    if solution is not None:
        assert is_rotation(solution.rotation) and np.all(np.isfinite(solution.quaternion))


@examples(500)
@given(hnp.arrays(np.float64, (3, 3), elements=st.floats(-10, 10)), st.lists(st.floats(-10, 10), min_size=3,
                                                                             max_size=3))
def test_rotation_conversions_on_arbitrary_matrices(matrix, rotvec):
    q = matrix_to_quaternion(matrix)  # any finite matrix: a finite unit quaternion
    assert np.all(np.isfinite(q)) and abs(np.linalg.norm(q) - 1.0) < 1e-9
    rotation = rotation_vector_to_matrix(np.array(rotvec))
    assert is_rotation(rotation)
    assert is_rotation(quaternion_to_matrix(matrix_to_quaternion(rotation)))
    errors = attitude_error(rotation, np.eye(3))
    assert np.all(np.isfinite(errors))


# ============================================================================ defects found, fixed
def test_pixel_to_ray_of_no_points_with_distortion():
    """Found by fuzzing: cv2.undistortPoints returns None for no points (an AttributeError); no points give no rays."""
    rays = CAMERAS["distorted"].pixel_to_ray(np.zeros(0), np.zeros(0))
    assert rays.shape == (0, 3)


def test_zero_quaternion_is_refused():
    with np.errstate(all="ignore"):
        refused(quaternion_to_matrix, np.zeros(4), match="quaternions must be finite and non-zero")


@pytest.mark.parametrize("solver, body", [(davenport_q_method, [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
                                          (svd_attitude, [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
                                          (quest, [[0.0, 0.0, 1.0], [0.0, 0.0, 1.35e154]])])
def test_zero_or_overflowing_vectors_are_refused(solver, body):
    """
    Found by fuzzing.

    LinAlgError (or a NaN attitude) for a zero vector, and for quest a vector whose norm
    overflows; the documented refusal is a ValueError.
    """
    with np.errstate(all="ignore"):
        refused(solver, np.array(body), np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), 1e-4,
                match="vectors must be finite and non-zero")
