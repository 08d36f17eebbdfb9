# SPDX-License-Identifier: Apache-2.0
"""
Levenberg-Marquardt for small dense least-squares problems, plain or with a soft-L1 loss.

A one-frame camera refinement has ~8 parameters and a few hundred residuals: each of its three
solves takes ~5 evaluations, and scipy.optimize.least_squares's fixed cost per call (~0.5 ms)
was half of it (see models/camera_calibration.py). Here a step is one small normal-equation
solve. The soft-L1 loss rho(z) = 2 (sqrt(1 + z) - 1), z = (r / c)^2, applied to each residual
as scipy's loss="soft_l1" does, is minimized by iteratively reweighted least squares (weights
rho'(z) = 1 / sqrt(1 + z)): the same minimum, reached by a different path.
"""
from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

MAX_ITERATIONS = 100
# chi^2 still to gain that ends the fit: x within 1e-3 of a sigma of the minimum (residuals whitened).
DECREMENT_TOLERANCE = 1e-6
STEP_TOLERANCE = 1e-10  # relative parameter change that ends the fit


class DenseFit(NamedTuple):
    """x: the solution; residual, jacobian: the evaluation there (unweighted); evaluations: model calls."""

    x: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    evaluations: int


def _cost(residual: np.ndarray, soft_l1_scale: float | None) -> float:
    if soft_l1_scale is None:
        return 0.5 * float(residual @ residual)
    z = (residual / soft_l1_scale) ** 2
    return soft_l1_scale ** 2 * float(np.sum(np.sqrt(1.0 + z) - 1.0))


def dense_least_squares(evaluate: Callable, x0: np.ndarray, row_weights: np.ndarray | None = None,
                        soft_l1_scale: float | None = None) -> DenseFit:
    """
    Minimize sum rho(r_i^2) over x by Levenberg-Marquardt (Marquardt's diagonal scaling).

    evaluate(x) -> (residual (M,), jacobian (M, P)), both unweighted; row_weights (M,) multiply
    each residual (0 leaves it out; None: all 1); soft_l1_scale: the soft-L1 loss's transition
    c in the residual's units (None: plain least squares). Stops when a full Gauss-Newton step
    would lower the sum of squares by less than DECREMENT_TOLERANCE, a step moves x by less than
    STEP_TOLERANCE (relative), or after MAX_ITERATIONS steps; a step that raises the cost is
    not taken (the damping is raised instead).
    """
    x = np.asarray(x0, float).copy()
    rows = np.ones(0) if row_weights is None else np.asarray(row_weights, float)

    def weighted(params):
        residual, jacobian = evaluate(params)
        if row_weights is None:
            return residual, jacobian, residual, jacobian
        return residual, jacobian, residual * rows, jacobian * rows[:, None]

    residual, jacobian, r, j = weighted(x)
    cost = _cost(r, soft_l1_scale)
    evaluations, damping = 1, 1e-3
    for _ in range(MAX_ITERATIONS):
        # soft-L1: reweighted normal equations (rho' per residual), the loss's gradient exact.
        w = np.ones_like(r) if soft_l1_scale is None else 1.0 / np.sqrt(1.0 + (r / soft_l1_scale) ** 2)
        normal = j.T @ (j * w[:, None])
        gradient = j.T @ (w * r)
        try:  # the cost a full Gauss-Newton step would still gain: none left, a minimum
            decrement = float(gradient @ np.linalg.solve(normal, gradient))
        except np.linalg.LinAlgError:
            decrement = np.inf
        if decrement <= DECREMENT_TOLERANCE:
            break
        diagonal = np.maximum(np.diag(normal), 1e-300)
        while True:
            try:
                step = -np.linalg.solve(normal + damping * np.diag(diagonal), gradient)
            except np.linalg.LinAlgError:
                step = np.full_like(x, np.nan)
            trial = x + step
            if np.all(np.isfinite(trial)):
                trial_residual, trial_jacobian, trial_r, trial_j = weighted(trial)
                evaluations += 1
                trial_cost = _cost(trial_r, soft_l1_scale)
                if trial_cost <= cost:
                    break
            damping *= 10.0
            if damping > 1e12:  # no step lowers the cost: a minimum to rounding
                return DenseFit(x, residual, jacobian, evaluations)
        x, residual, jacobian, r, j, cost = trial, trial_residual, trial_jacobian, trial_r, trial_j, trial_cost
        damping = max(damping / 10.0, 1e-12)
        if np.linalg.norm(step) <= STEP_TOLERANCE * (np.linalg.norm(x) + STEP_TOLERANCE):
            break
    return DenseFit(x, residual, jacobian, evaluations)
