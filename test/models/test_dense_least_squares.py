# SPDX-License-Identifier: Apache-2.0
"""The small dense Levenberg-Marquardt reaches scipy.optimize.least_squares's minima (plain, soft-L1, row weights)."""
import numpy as np
import pytest
from scipy.optimize import least_squares

from star_tracker.models.dense_least_squares import dense_least_squares


def _decay_problem(seed: int, outliers: int = 0):
    """Return the model and Jacobian of y = a exp(-b t) + c, with unit noise and `outliers` gross errors."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 4.0, 60)
    y = 20.0 * np.exp(-1.3 * t) + 2.0 + rng.normal(0.0, 1.0, t.size)
    y[rng.choice(t.size, outliers, replace=False)] += 25.0

    def evaluate(p):
        a, b, c = p
        e = np.exp(-b * t)
        return a * e + c - y, np.column_stack([e, -a * t * e, np.ones_like(t)])

    return evaluate


def _sigmas_apart(a, b, evaluate) -> float:
    """Largest |a - b| in 1-sigma units of the parameters (unit-noise covariance (J^T J)^-1 at b)."""
    _, jacobian = evaluate(b)
    sigma = np.sqrt(np.diag(np.linalg.inv(jacobian.T @ jacobian)))
    return float(np.max(np.abs(a - b) / sigma))


# The fit stops within 1e-3 sigma of the minimum (DECREMENT_TOLERANCE); scipy's own stop is looser.
SIGMAS = 1e-2


@pytest.mark.parametrize("seed", range(5))
def test_plain_minimum_is_scipys(seed):
    evaluate = _decay_problem(seed)
    start = np.array([5.0, 0.3, 0.0])
    ours = dense_least_squares(evaluate, start)
    theirs = least_squares(lambda p: evaluate(p)[0], start, jac=lambda p: evaluate(p)[1], xtol=1e-14, ftol=1e-14)
    assert _sigmas_apart(ours.x, theirs.x, evaluate) < SIGMAS
    assert np.allclose(ours.residual, evaluate(ours.x)[0])  # returned at the solution


@pytest.mark.parametrize("seed", range(5))
def test_soft_l1_minimum_is_scipys_and_resists_outliers(seed):
    evaluate = _decay_problem(seed, outliers=6)
    start = np.array([5.0, 0.3, 0.0])
    ours = dense_least_squares(evaluate, start, soft_l1_scale=2.0)
    theirs = least_squares(lambda p: evaluate(p)[0], start, jac=lambda p: evaluate(p)[1], loss="soft_l1", f_scale=2.0,
                           xtol=1e-14, ftol=1e-14, gtol=1e-14)
    assert _sigmas_apart(ours.x, theirs.x, evaluate) < SIGMAS
    plain = dense_least_squares(evaluate, start)
    truth = np.array([20.0, 1.3, 2.0])
    assert abs(ours.x[2] - truth[2]) < abs(plain.x[2] - truth[2])  # the outliers' +25 drag the plain offset


def test_zero_row_weights_leave_rows_out():
    evaluate = _decay_problem(7, outliers=4)
    residual, _ = evaluate(np.array([20.0, 1.3, 2.0]))
    keep = (np.abs(residual) < 10.0).astype(float)
    ours = dense_least_squares(evaluate, np.array([5.0, 0.3, 0.0]), row_weights=keep)
    rows = keep > 0
    theirs = least_squares(lambda p: evaluate(p)[0][rows], np.array([5.0, 0.3, 0.0]),
                           jac=lambda p: evaluate(p)[1][rows], xtol=1e-14, ftol=1e-14)
    assert keep.sum() < keep.size
    assert _sigmas_apart(ours.x, theirs.x, evaluate) < SIGMAS


def test_a_start_at_the_minimum_returns_it_after_one_evaluation():
    evaluate = _decay_problem(3)
    best = dense_least_squares(evaluate, np.array([5.0, 0.3, 0.0]))
    again = dense_least_squares(evaluate, best.x)
    assert again.evaluations == 1 and np.array_equal(again.x, best.x)
