# SPDX-License-Identifier: Apache-2.0
"""The camera fit's Levenberg-Marquardt reaches the same minima as scipy's least_squares."""
import numpy as np
import pytest
from scipy import sparse
from scipy.optimize import least_squares

from star_tracker.models.damped_least_squares import damped_least_squares


def _exponential_problem(seed: int, outliers: int):
    """Return the residual model of y = a exp(-b t) + c in unit noise, `outliers` points 40 sigma off; truth."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 4.0, 80)
    truth = np.array([50.0, 0.8, 5.0])
    y = truth[0] * np.exp(-truth[1] * t) + truth[2] + rng.normal(size=t.size)
    y[rng.choice(t.size, outliers, replace=False)] += 40.0

    def evaluate(p):
        e = np.exp(-p[1] * t)
        return p[0] * e + p[2] - y, np.column_stack([e, -p[0] * t * e, np.ones_like(t)])

    return evaluate, truth


def _sigmas(evaluate, x):
    """1-sigma of each parameter at x (unit noise)."""
    jac = evaluate(x)[1]
    return np.sqrt(np.diag(np.linalg.inv(jac.T @ jac)))


def _assert_same_minimum(ours, theirs, sigmas):
    """Within 1 % of each parameter's sigma: the solvers' tolerances, far below what a fit reports."""
    assert np.all(np.abs(ours - theirs) < 0.01 * sigmas), (ours, theirs, sigmas)


@pytest.mark.parametrize("seed", range(5))
def test_plain_minimum_matches_scipy(seed):
    evaluate, truth = _exponential_problem(seed, outliers=0)
    start = np.array([30.0, 0.3, 0.0])
    ours = damped_least_squares(evaluate, start)
    theirs = least_squares(lambda p: evaluate(p)[0], start, jac=lambda p: evaluate(p)[1], xtol=1e-12, ftol=1e-12)
    _assert_same_minimum(ours.x, theirs.x, _sigmas(evaluate, theirs.x))
    assert np.all(np.abs(ours.x - truth) < [2.0, 0.1, 1.0])  # the truth within a few sigma
    np.testing.assert_allclose(ours.fun, evaluate(ours.x)[0])


@pytest.mark.parametrize("seed", range(5))
def test_soft_l1_minimum_matches_scipy_and_resists_outliers(seed):
    evaluate, truth = _exponential_problem(seed, outliers=8)
    start = np.array([30.0, 0.3, 0.0])
    plain = damped_least_squares(evaluate, start)
    robust = damped_least_squares(evaluate, plain.x, robust_scale=3.0)
    theirs = least_squares(lambda p: evaluate(p)[0], start, jac=lambda p: evaluate(p)[1], loss="soft_l1",
                           f_scale=3.0, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    _assert_same_minimum(robust.x, theirs.x, _sigmas(evaluate, theirs.x))
    # The outliers pull the plain fit's offset up; the robust one stays nearer the truth.
    assert abs(robust.x[2] - truth[2]) < abs(plain.x[2] - truth[2])


def test_rows_leave_residuals_out_and_sparse_jacobians_work():
    evaluate, truth = _exponential_problem(3, outliers=8)
    r0, _ = evaluate(truth)
    keep = (np.abs(r0) < 10.0).astype(float)  # the outliers left out

    def sparse_evaluate(p):
        r, jac = evaluate(p)
        return r, sparse.csr_matrix(jac)

    dense = damped_least_squares(evaluate, np.array([30.0, 0.3, 0.0]), rows=keep)
    sparse_fit = damped_least_squares(sparse_evaluate, np.array([30.0, 0.3, 0.0]), rows=keep)
    inliers = keep > 0
    theirs = least_squares(lambda p: evaluate(p)[0][inliers], np.array([30.0, 0.3, 0.0]),
                           jac=lambda p: evaluate(p)[1][inliers], xtol=1e-12, ftol=1e-12)
    _assert_same_minimum(dense.x, theirs.x, _sigmas(evaluate, theirs.x))
    np.testing.assert_allclose(sparse_fit.x, dense.x, rtol=1e-8)
    assert np.all(dense.fun[~inliers] == 0.0)


def test_non_finite_start_is_refused_like_scipy():
    evaluate, _ = _exponential_problem(0, outliers=0)

    def broken(p):
        r, jac = evaluate(p)
        r[3] = np.nan
        return r, jac

    with pytest.raises(ValueError, match="not finite"):
        damped_least_squares(broken, np.array([30.0, 0.3, 0.0]))
