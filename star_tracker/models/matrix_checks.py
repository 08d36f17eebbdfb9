# SPDX-License-Identifier: Apache-2.0
"""
What makes an input matrix or rate unusable, in words: each check returns the problem or None.

Shared by the fusion's observation screening, FusionState.fused_at (the body rate) and
alignment filter (the heads' solutions), and by AppliedMotion and the identifier's smear aid
(a gyro path's offset covariance), so every entry point refuses the same inputs the same way.
"""
from __future__ import annotations

import numpy as np

ROTATION_TOLERANCE = 1e-6  # largest |R^T R - I| entry and |det R - 1| of an accepted rotation


def rotation_problem(matrix: np.ndarray) -> str | None:
    """Return why `matrix` is not a proper 3x3 rotation (shape, NaN, not orthonormal, a reflection), None if it is."""
    matrix = np.asarray(matrix, dtype=float)
    if matrix.shape != (3, 3):
        return f"shape {matrix.shape}, not (3, 3)"
    if not np.all(np.isfinite(matrix)):
        return "not finite"
    orthogonality = float(np.max(np.abs(matrix.T @ matrix - np.eye(3))))
    if orthogonality > ROTATION_TOLERANCE:
        return f"not orthonormal (max |R^T R - I| = {orthogonality:.2e})"
    if abs(np.linalg.det(matrix) - 1.0) > ROTATION_TOLERANCE:
        return "a reflection (det = -1)"
    return None


def covariance_problem(matrix: np.ndarray, *, definite: bool = True) -> str | None:
    """Return why `matrix` is not a finite symmetric positive (semi-, definite=False) definite 3x3, None if it is."""
    matrix = np.asarray(matrix, dtype=float)
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        return f"not a finite (3, 3) matrix (shape {matrix.shape})"
    if not np.allclose(matrix, matrix.T, rtol=1e-6, atol=1e-300):
        return "not symmetric"
    smallest = float(np.linalg.eigvalsh(matrix).min())
    scale = max(float(np.abs(matrix).max()), 1e-300)
    if smallest <= 0.0 if definite else smallest < -1e-9 * scale:
        return f"not positive {'definite' if definite else 'semi-definite'} (smallest eigenvalue {smallest:.3e})"
    return None


def rate_problem(rate: np.ndarray, covariance: np.ndarray) -> str | None:
    """Return why a body rate (3,) [rad/s] with its covariance (3, 3) [rad^2/s^2] is unusable, None if it is usable."""
    rate = np.asarray(rate, dtype=float)
    if rate.shape != (3,) or not np.all(np.isfinite(rate)):
        return f"rate must be 3 finite values [rad/s], got {rate!r}"
    problem = covariance_problem(covariance, definite=False)
    return None if problem is None else f"rate covariance is {problem}"
