# SPDX-License-Identifier: Apache-2.0
"""
The camera calibration's model of one frame, compiled (numba): whitened pixel residuals and their derivatives.

camera_calibration evaluates it tens of times per fit on ~10-150 stars, where numpy's
per-operation overhead was most of the cost (~100 us a call in numpy, a few here).
"""
from __future__ import annotations

import numpy as np
from numba import njit

# Camera parameter codes, in camera_calibration's parameter names.
PARAMETER_CODES = {"f": 0, "cx": 1, "cy": 2, "k1": 3, "k2": 4}


def frame_rows(stars: np.ndarray, rotation: np.ndarray, right_jacobian: np.ndarray, intrinsics: np.ndarray,
               distortion: np.ndarray, codes: np.ndarray, whiten: np.ndarray, measured: np.ndarray,
               residual: np.ndarray, by_rotation: np.ndarray, by_camera: np.ndarray) -> None:
    """
    Write one frame's whitened residuals and derivatives into residual, by_rotation, by_camera.

    stars (n, 3): catalogue unit vectors (ICRS); rotation (3, 3): sensor -> ICRS at the trial
    attitude (a star's sensor ray is star @ rotation); right_jacobian (3, 3): J_r of the trial
    rotation vector; intrinsics (fx, fy, cx, cy) [px]; distortion (k1, k2, p1, p2, k3);
    codes (P,) int64: the fitted camera parameters (PARAMETER_CODES; f as a log scale of
    fx and fy); whiten (n, 2, 2); measured (n, 2) [px]. Out: residual (n, 2) = W (predicted -
    measured); by_rotation (n, 2, 3) = W d pixel / d theta; by_camera (n, 2, P) = W d pixel /
    d parameter.
    """
    _frame_rows(stars, rotation, right_jacobian, intrinsics, distortion, codes, whiten, measured, residual,
                by_rotation, by_camera)


@njit(cache=True)
def _frame_rows(stars, rotation, right_jacobian, intrinsics, distortion, codes, whiten, measured, residual,
                by_rotation, by_camera):
    """Compute frame_rows (compiled)."""
    fx, fy, cx, cy = intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3]
    k1, k2, p1, p2, k3 = distortion[0], distortion[1], distortion[2], distortion[3], distortion[4]
    b = np.empty((2, 3))
    turned = np.empty((2, 3))
    raw = np.empty((2, 3))
    camera = np.empty((2, codes.size))
    for i in range(stars.shape[0]):
        ray0 = stars[i, 0] * rotation[0, 0] + stars[i, 1] * rotation[1, 0] + stars[i, 2] * rotation[2, 0]
        ray1 = stars[i, 0] * rotation[0, 1] + stars[i, 1] * rotation[1, 1] + stars[i, 2] * rotation[2, 1]
        ray2 = stars[i, 0] * rotation[0, 2] + stars[i, 1] * rotation[1, 2] + stars[i, 2] * rotation[2, 2]
        z = ray2 if abs(ray2) > 1e-9 else 1e-9
        inv_z = 1.0 / z
        x, y = ray0 * inv_z, ray1 * inv_z
        # Brown-Conrady as CameraModel.distort_normalized (test_calibration_kernel holds them equal), and its
        # derivatives by (x, y).
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        slope = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3))
        cross = slope * x * y + 2.0 * p1 * x + 2.0 * p2 * y
        a11 = radial + slope * x * x + 2.0 * p1 * y + 6.0 * p2 * x
        a22 = radial + slope * y * y + 6.0 * p1 * y + 2.0 * p2 * x
        dx = fx * xd + cx - measured[i, 0]
        dy = fy * yd + cy - measured[i, 1]
        # d pixel / d ray: diag(fx, fy) · d distorted / d normalized · d normalized / d ray.
        b[0, 0], b[0, 1], b[0, 2] = fx * a11 * inv_z, fx * cross * inv_z, -fx * (a11 * x + cross * y) * inv_z
        b[1, 0], b[1, 1], b[1, 2] = fy * cross * inv_z, fy * a22 * inv_z, -fy * (cross * x + a22 * y) * inv_z
        # d ray / d theta = [ray]x J_r: a row of b times [ray]x is that row x ray.
        for j in range(2):
            turned[j, 0] = b[j, 1] * ray2 - b[j, 2] * ray1
            turned[j, 1] = b[j, 2] * ray0 - b[j, 0] * ray2
            turned[j, 2] = b[j, 0] * ray1 - b[j, 1] * ray0
            for c in range(3):
                raw[j, c] = (turned[j, 0] * right_jacobian[0, c] + turned[j, 1] * right_jacobian[1, c]
                             + turned[j, 2] * right_jacobian[2, c])
        for c in range(codes.size):
            code = codes[c]
            if code == 0:
                camera[0, c], camera[1, c] = fx * xd, fy * yd
            elif code == 1:
                camera[0, c], camera[1, c] = 1.0, 0.0
            elif code == 2:
                camera[0, c], camera[1, c] = 0.0, 1.0
            elif code == 3:
                camera[0, c], camera[1, c] = fx * x * r2, fy * y * r2
            else:
                camera[0, c], camera[1, c] = fx * x * r2 * r2, fy * y * r2 * r2
        w00, w01, w10, w11 = whiten[i, 0, 0], whiten[i, 0, 1], whiten[i, 1, 0], whiten[i, 1, 1]
        residual[i, 0] = w00 * dx + w01 * dy
        residual[i, 1] = w10 * dx + w11 * dy
        for c in range(3):
            by_rotation[i, 0, c] = w00 * raw[0, c] + w01 * raw[1, c]
            by_rotation[i, 1, c] = w10 * raw[0, c] + w11 * raw[1, c]
        for c in range(codes.size):
            by_camera[i, 0, c] = w00 * camera[0, c] + w01 * camera[1, c]
            by_camera[i, 1, c] = w10 * camera[0, c] + w11 * camera[1, c]


def warm_up() -> None:
    """Compile (or load from the cache) the kernel now, not at the first calibration."""
    one = np.zeros((1, 3))
    one[0, 2] = 1.0
    frame_rows(one, np.eye(3), np.eye(3), np.array([100.0, 100.0, 50.0, 50.0]), np.zeros(5),
               np.arange(5, dtype=np.int64), np.eye(2)[None].copy(), np.zeros((1, 2)), np.empty((1, 2)),
               np.empty((1, 2, 3)), np.empty((1, 2, 5)))
