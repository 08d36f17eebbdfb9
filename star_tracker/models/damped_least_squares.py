# SPDX-License-Identifier: Apache-2.0
"""
Levenberg-Marquardt for the small, analytic-Jacobian problems of the camera fit.

The camera fit of a solve has 4-8 parameters and 20-200 stars, and runs 2-6 times per solve;
scipy.optimize.least_squares spent ~2 ms per fit there, most of it in its per-call and
per-step set-up rather than in arithmetic. This solver minimises the same costs (plain
least squares, or scipy's "soft_l1" loss) in a few normal-equation steps.

Cost: 0.5 sum r_i^2, or with a robust scale s, 0.5 s^2 sum rho(r_i^2 / s^2) with
rho(z) = 2 (sqrt(1 + z) - 1) (soft L1: quadratic within s, linear beyond). A row's cost has
slope r w and curvature w^3 in r (w = 1 / sqrt(1 + z)): the robust steps are Newton steps with
that curvature (Gauss-Newton in the model), damped until they lower the robust cost.
"""
from __future__ import annotations

import warnings
from typing import Callable, NamedTuple

import numpy as np

# Stop when the Gauss-Newton step would lower the cost by less than this [cost units: half a
# whitened chi^2]: the parameters are then within ~1e-3 of their own sigmas of the minimum.
COST_TOLERANCE = 1e-6
MAX_EVALUATIONS = 100
_DAMPING_START = 1e-4  # Marquardt's lambda, relative to each parameter's own curvature
_DAMPING_DOWN, _DAMPING_UP = 0.2, 10.0


class LeastSquaresFit(NamedTuple):
    """x: the parameters at the minimum; fun: residuals there (rows as given); jac: their Jacobian (dense or sparse)."""

    x: np.ndarray
    fun: np.ndarray
    jac: object
    evaluations: int


def damped_least_squares(evaluate: Callable, x0: np.ndarray, robust_scale: float | None = None,
                         rows: np.ndarray | None = None) -> LeastSquaresFit:
    """
    Minimise the cost (module docstring) of the residuals of `evaluate`, starting at x0.

    evaluate(x) -> (r (M,), J (M, P) dense or scipy.sparse): residuals and their Jacobian;
    robust_scale: s of the soft-L1 loss (None: plain least squares); rows: (M,) factors
    applied to the residual rows (0 leaves a row out), or None. ValueError when the residuals
    at x0 are not finite.
    """
    def residual_and_jacobian(x):
        r, jac = evaluate(x)
        if rows is None:
            return r, jac
        return r * rows, _scale_rows(jac, rows)

    def cost_of(r):
        if robust_scale is None:
            return 0.5 * float(r @ r)
        z = (r / robust_scale) ** 2
        return robust_scale ** 2 * float(np.sum(np.sqrt(1.0 + z) - 1.0))

    x = np.asarray(x0, dtype=float).copy()
    r, jac = residual_and_jacobian(x)
    cost = cost_of(r)
    if not np.isfinite(cost):
        raise ValueError("residuals are not finite at the starting point")  # as scipy's least_squares
    evaluations, damping = 1, _DAMPING_START
    while evaluations < MAX_EVALUATIONS:
        slope = np.ones_like(r) if robust_scale is None else 1.0 / np.sqrt(1.0 + (r / robust_scale) ** 2)
        curved = slope ** 3
        weighted = _scale_rows(jac, curved)
        normal = jac.T @ weighted
        gradient = np.asarray(jac.T @ (slope * r)).ravel()
        diagonal = np.asarray(normal.diagonal()).ravel()
        curvature = np.maximum(diagonal, 1e-12 * max(float(np.max(diagonal)), 1e-300))
        newton = _damped_step(normal, curvature, 1e-12, gradient)
        if newton is not None and -0.5 * float(gradient @ newton) < COST_TOLERANCE:
            break  # at the minimum: the undamped step would gain nothing
        accepted = False
        while evaluations < MAX_EVALUATIONS:
            step = _damped_step(normal, curvature, damping, gradient)
            if step is None:
                damping *= _DAMPING_UP
                if damping > 1e12:
                    break
                continue
            trial = x + step
            r_trial, jac_trial = residual_and_jacobian(trial)
            evaluations += 1
            cost_trial = cost_of(r_trial)
            if np.isfinite(cost_trial) and cost_trial <= cost:
                x, r, jac, cost = trial, r_trial, jac_trial, cost_trial
                damping = max(damping * _DAMPING_DOWN, 1e-12)
                accepted = True
                break
            damping *= _DAMPING_UP
            if damping > 1e12:
                break
        if not accepted:
            break  # no damping lowers the cost: as close to the minimum as the arithmetic gets
    return LeastSquaresFit(x, r, jac, evaluations)


def _scale_rows(jac, factors: np.ndarray):
    """Return `jac` (dense or scipy.sparse) with row i multiplied by factors[i]."""
    return jac.multiply(factors[:, None]).tocsr() if hasattr(jac, "multiply") else jac * factors[:, None]


def _damped_step(normal, curvature: np.ndarray, damping: float, gradient: np.ndarray) -> np.ndarray | None:
    """
    Solve (normal + damping diag(curvature)) step = -gradient; None if singular or not finite.

    A sparse normal matrix (several frames: each frame's rotation couples only with itself and
    the camera) is solved sparse, its cost growing with the frames rather than their cube.
    """
    if hasattr(normal, "tocsc"):
        from scipy import sparse
        from scipy.sparse import linalg as sparse_linalg

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", sparse_linalg.MatrixRankWarning)
            step = sparse_linalg.spsolve((normal + sparse.diags(damping * curvature)).tocsc(), -gradient)
    else:
        try:
            step = np.linalg.solve(normal + np.diag(damping * curvature), -gradient)
        except np.linalg.LinAlgError:
            return None
    return step if np.all(np.isfinite(step)) else None
