# SPDX-License-Identifier: Apache-2.0
"""The compiled one-frame calibration model against CameraModel's projection and finite differences."""
from __future__ import annotations

import math

import numpy as np

from star_tracker.models.attitude import radec_roll_to_matrix, rotation_vector_to_matrix
from star_tracker.models.calibration_kernel import PARAMETER_CODES, frame_rows
from star_tracker.models.camera import CameraModel

NAMES = ("f", "cx", "cy", "k1", "k2")


def _camera(params: np.ndarray) -> CameraModel:
    """Return the camera of (log f scale, cx offset, cy offset, k1, k2) around a 20-degree 1024 x 768 lens."""
    base = CameraModel.from_fov(1024, 768, math.radians(20.0))
    scale = math.exp(params[0])
    return CameraModel(base.width, base.height, base.fx * scale, base.fy * scale, base.cx + params[1],
                       base.cy + params[2], (params[3], params[4], 1e-4, -2e-4, 0.01))


def _right_jacobian(theta: np.ndarray) -> np.ndarray:
    """Return J_r of a rotation vector by finite differences: Exp(theta + d) = Exp(theta) Exp(J_r d)."""
    base = rotation_vector_to_matrix(theta)
    out = np.empty((3, 3))
    for j in range(3):
        step = np.zeros(3)
        step[j] = 1e-7
        delta = base.T @ rotation_vector_to_matrix(theta + step)
        out[:, j] = np.array([delta[2, 1], delta[0, 2], delta[1, 0]]) / 1e-7
    return out


def _evaluate(stars, start, theta, camera_params, whiten, measured):
    """Return the kernel's whitened residual (n, 2), d / d theta (n, 2, 3), d / d camera (n, 2, 5)."""
    camera = _camera(camera_params)
    n = stars.shape[0]
    residual, by_rotation, by_camera = np.empty((n, 2)), np.empty((n, 2, 3)), np.empty((n, 2, 5))
    frame_rows(stars, start @ rotation_vector_to_matrix(theta), _right_jacobian(theta),
               np.array([camera.fx, camera.fy, camera.cx, camera.cy]), np.array(camera.distortion),
               np.array([PARAMETER_CODES[name] for name in NAMES], np.int64), whiten, measured, residual,
               by_rotation, by_camera)
    return residual, by_rotation, by_camera


def test_the_kernel_is_the_projection_and_its_derivatives():
    rng = np.random.default_rng(3)
    start = radec_roll_to_matrix(1.0, 0.4, 0.2)
    pixels = np.column_stack([rng.uniform(0, 1023, 40), rng.uniform(0, 767, 40)])
    rays = _camera(np.zeros(5)).pixel_to_ray(pixels[:, 0], pixels[:, 1])
    stars = np.ascontiguousarray(rays @ start.T)  # ICRS directions seen at those pixels
    theta = np.array([2e-4, -1e-4, 3e-4])
    camera_params = np.array([0.01, 1.5, -2.0, -0.05, 0.01])
    measured = pixels + rng.normal(0.0, 0.3, pixels.shape)
    whiten = np.linalg.cholesky(np.linalg.inv(np.array([[0.2, 0.05], [0.05, 0.3]])))[None].repeat(40, 0)
    whiten = np.ascontiguousarray(np.transpose(whiten, (0, 2, 1)))
    residual, by_rotation, by_camera = _evaluate(stars, start, theta, camera_params, whiten, measured)
    # The residual: the camera's own projection (cv2-compatible Brown-Conrady), whitened.
    u, v, _ = _camera(camera_params).project(stars @ (start @ rotation_vector_to_matrix(theta)))
    expected = np.einsum("nij,nj->ni", whiten, np.column_stack([u, v]) - measured)
    assert np.max(np.abs(residual - expected)) < 1e-9
    # The derivatives: central differences of that residual.
    for j in range(3):
        step = np.zeros(3)
        step[j] = 1e-6
        plus = _evaluate(stars, start, theta + step, camera_params, whiten, measured)[0]
        minus = _evaluate(stars, start, theta - step, camera_params, whiten, measured)[0]
        assert np.allclose((plus - minus) / 2e-6, by_rotation[:, :, j], rtol=1e-5, atol=1e-3)
    for j, h in enumerate((1e-7, 1e-5, 1e-5, 1e-7, 1e-7)):
        step = np.zeros(5)
        step[j] = h
        plus = _evaluate(stars, start, theta, camera_params + step, whiten, measured)[0]
        minus = _evaluate(stars, start, theta, camera_params - step, whiten, measured)[0]
        assert np.allclose((plus - minus) / (2 * h), by_camera[:, :, j], rtol=1e-5, atol=1e-3), NAMES[j]
