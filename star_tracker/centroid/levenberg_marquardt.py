"""Weighted least squares by Levenberg-Marquardt on batches of windows: every spot of a batch
fitted at once, each in its own window, one spot's failure never affecting another's (the
streak fits' solver; generic in the model, which the caller evaluates)."""
from __future__ import annotations

import numpy as np

from .streak_model import StreakWindows


def _damping_floor(normal: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """1e-10 of the total information, per parameter in the units of `scale` (n, P): keeps
    degenerate systems solvable (a zero-length streak has no information on its angle)."""
    diag = np.diagonal(normal, axis1=1, axis2=2)
    return 1e-10 * np.sum(diag * scale * scale, axis=1, keepdims=True) / (scale * scale) + 1e-300


REWEIGHT_STEPS = 3  # linearizations whose model sets the weights (then they stay)
DECREMENT_TOLERANCE = 1e-3  # chi^2 still to gain: stop within ~3 % of a sigma of the minimum


def levenberg_marquardt(evaluate, params, win: StreakWindows, valid, noise: float, gain: float, iterations: int,
                         max_step, constrain, scale_of, undetermined=None):
    """Weighted least squares by Levenberg-Marquardt, all spots at once (those still moving).

    evaluate(index, params (n, P)) -> aug (n, P + 1, M) float32: the jacobian (P rows) and the
    model [ADU] over the M window pixels of the spots `index` of the batch;
    max_step(params) -> (n, P) trust-region half-widths; constrain(index, params) -> params
    projected onto the feasible set; scale_of(params) -> (n, P) typical parameter units;
    undetermined(params, covariance (n, P, P)) -> two (n, P) bool masks: parameters left out
    of the convergence test, and parameters held fixed in the step (a zero-length streak's
    length and angle, see fit_streaks).

    Weights 1 / (max(model, 0) / gain + noise^2) follow the model for REWEIGHT_STEPS
    linearizations, then stay: reweighting at every step changes the objective under the
    acceptance test and can cycle at low SNR. With noisy data the Gauss-Newton matrix N,
    which omits the residuals' second-order term, can be far from the chi^2 curvature along
    a poorly measured direction (a faint streak's ends): steps overshoot to the mirror
    point or crawl. So steps use B = N + S, S a symmetric rank-one correction per step
    that makes B's curvature along the last step match the change of the gradient (secant
    condition, once the weights are fixed); damping follows the ratio of actual to
    predicted chi^2 decrease (Nielsen's rule). A spot stops when its Gauss-Newton decrement
    g^T N^-1 g (the chi^2 still to gain) is below DECREMENT_TOLERANCE. The Fisher matrix
    returned is N.
    Returns params, Fisher matrices (N, P, P) at the solution, done (N,) bool (a minimum was
    reached within the iterations), chi2 (N,) at the solution (inf where never evaluated)."""
    n, n_par = params.shape
    noise2, inv_gain = np.float32(noise * noise), np.float32(1.0 / gain)
    normal = np.zeros((n, n_par, n_par))
    grad = np.zeros((n, n_par))
    chi2 = np.full(n, np.inf)
    weights = np.zeros_like(win.data)
    lam = np.full(n, 1e-3)
    nu = np.full(n, 2.0)
    done = np.zeros(n, bool)
    reweighted = np.zeros(n, np.int64)
    correction = np.zeros((n, n_par, n_par))  # S
    eye = np.eye(n_par)

    def weighted_sum(a, b):  # sum over pixels of a * b (float32), accumulated in float64
        return np.sum(a * b, axis=1, dtype=np.float64)

    def linearize(index, aug, residual):
        # aug: jacobian rows, then the model (replaced by the residual here)
        w = weights[index]
        fresh = reweighted[index] < REWEIGHT_STEPS
        if np.all(fresh):
            np.maximum(aug[:, n_par], 0.0, out=w)
            w *= inv_gain
            w += noise2
            np.divide(win.mask[index], w, out=w)
        elif np.any(fresh):
            w[fresh] = win.mask[index[fresh]] / (np.maximum(aug[fresh, n_par], 0.0) * inv_gain + noise2)
        reweighted[index] += 1
        aug[:, n_par] = residual
        weighted = aug * w[:, None, :]
        # One product gives the normal matrix and the gradient.
        products = np.matmul(weighted, aug.transpose(0, 2, 1)).astype(np.float64)
        weights[index] = w
        normal[index], grad[index] = products[:, :n_par, :n_par], products[:, :n_par, n_par]
        chi2[index] = weighted_sum(weighted[:, n_par], residual)

    active = np.flatnonzero(valid)
    if active.size:
        aug = evaluate(active, params[active])
        linearize(active, aug, win.data[active] - aug[:, n_par])
        active = active[np.isfinite(chi2[active])]
    for _ in range(iterations):
        if active.size == 0:
            break
        p, g = params[active], grad[active]
        floor = _damping_floor(normal[active], scale_of(p))
        floored = normal[active] + floor[:, :, None] * eye
        if undetermined is None:
            judged, hold = g, np.zeros(p.shape, bool)
        else:  # decrement over the other parameters, the undetermined ones held fixed
            skip, hold = undetermined(p, _batched_inverse(floored))
            judged = np.where(skip, 0.0, g)
            floored = np.where(skip[:, :, None] | skip[:, None, :], eye, floored)
        decrement = np.sum(_solve(floored, judged) * judged, axis=1)
        a = normal[active] + correction[active]
        finished = ~(decrement > DECREMENT_TOLERANCE)  # NaN: give up
        done[active[finished & np.isfinite(decrement)]] = True
        keep = ~finished
        active, p, a, g, floor, hold = active[keep], p[keep], a[keep], g[keep], floor[keep], hold[keep]
        if active.size == 0:
            break
        diag = np.diagonal(a, axis1=1, axis2=2)
        damped = a + (lam[active, None] * diag + floor)[:, :, None] * eye
        if np.any(hold):  # a free direction would take the whole trust region
            damped = np.where(hold[:, :, None] | hold[:, None, :], eye, damped)
        step = _solve(damped, np.where(hold, 0.0, g))
        over = np.max(np.abs(step) / max_step(p), axis=1)
        step /= np.maximum(over, 1.0)[:, None]  # trust region, direction kept
        trial = constrain(active, p + step)
        finite = np.all(np.isfinite(trial), axis=1)
        trial = np.where(finite[:, None], trial, p)  # a failed solve: evaluated, never taken
        step = trial - p
        aug = evaluate(active, trial)
        r = win.data[active] - aug[:, n_par]
        trial_chi2 = weighted_sum(weights[active] * r, r)
        old = chi2[active]
        actual = old - trial_chi2
        predicted = 2.0 * np.sum(step * g, axis=1) - np.einsum("ni,nij,nj->n", step, a, step)
        # The float32 model makes chi^2 uncertain by ~1e-3 for the brightest streaks: smaller
        # changes count as none (1e-3 in chi^2 is 3 % of a sigma).
        better = (actual >= -(1e-6 * old + 1e-3)) & finite
        ratio = actual / np.maximum(predicted, 1e-300)
        if np.any(better):
            idx = active[better]
            params[idx] = trial[better]
            # Measure curvature on steps with the same weights before and after, and large
            # enough that the gradient change stands above float32 rounding.
            frozen = (reweighted[idx] >= REWEIGHT_STEPS) & (predicted[better] > 1e-2)
            if better.all():
                linearize(idx, aug, r)
            else:
                linearize(idx, aug[better], r[better])
            _secant_update(correction, idx[frozen], step[better][frozen], a[better][frozen],
                           g[better][frozen] - grad[idx[frozen]])
            lam[idx] *= np.maximum(1.0 / 3.0, 1.0 - (2.0 * np.clip(ratio[better], 0.0, 1.0) - 1.0) ** 3)
            lam[idx] = np.maximum(lam[idx], 1e-9)
            nu[idx] = 2.0
        worse = active[~better]
        lam[worse] *= nu[worse]
        nu[worse] *= 2.0
        stuck = worse[lam[worse] > 1e12]  # no step lowers chi^2: a minimum to rounding
        done[stuck] = True
        active = active[~np.isin(active, stuck)]
    return params, normal, done, chi2


def _secant_update(correction, index, step, model_matrix, gradient_change) -> None:
    """S += (c - b) / b^2 (B step)(B step)^T with b = step^T B step, c = step^T (g_old -
    g_new) the measured curvature along the step, clipped to [b / 4, 4 b] (keeps B
    positive definite and a noisy measurement from flattening it)."""
    if index.size == 0:
        return
    b_step = np.matmul(model_matrix, step[:, :, None])[..., 0]
    b = np.sum(step * b_step, axis=1)
    c = np.clip(np.sum(step * gradient_change, axis=1), b / 4.0, 4.0 * b)
    ok = b > 0
    alpha = np.where(ok, (c - b) / np.where(ok, b * b, 1.0), 0.0)
    correction[index] += alpha[:, None, None] * b_step[:, :, None] * b_step[:, None, :]


def _solve(matrices: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Batched solve; a singular system gives NaN for its spot instead of failing the batch."""
    try:
        return np.linalg.solve(matrices, rhs[..., None])[..., 0]
    except np.linalg.LinAlgError:
        out = np.full(rhs.shape, np.nan)
        for i in range(rhs.shape[0]):
            try:
                out[i] = np.linalg.solve(matrices[i], rhs[i])
            except np.linalg.LinAlgError:
                pass
        return out


def inverse_fisher(normal: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Inverse of the Fisher matrices (n, P, P); degenerate directions floored (see
    _damping_floor): they come out with huge variance instead of failing the batch."""
    floored = normal + _damping_floor(normal, scale)[:, :, None] * np.eye(normal.shape[1])[None]
    return _batched_inverse(floored)


def _batched_inverse(matrices: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.inv(matrices)
    except np.linalg.LinAlgError:
        out = np.full(matrices.shape, np.nan)
        for i in range(matrices.shape[0]):
            try:
                out[i] = np.linalg.inv(matrices[i])
            except np.linalg.LinAlgError:
                pass
        return out
