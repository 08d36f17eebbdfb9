# SPDX-License-Identifier: Apache-2.0
"""
Weighted least squares by Levenberg-Marquardt on batches of windows.

Every spot of a batch fitted at once, each in its own window, one spot's failure never
affecting another's (the path and group streak fits' solver; generic in the model, which
the caller evaluates). The free streak fit runs the same algorithm compiled, one spot at a
time (streak.free_fit_kernel).
"""
from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from .model import StreakWindows


def _damping_floor(normal: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """
    1e-10 of the total information, per parameter in the units of `scale` (n, P).

    Keeps degenerate systems solvable (a zero-length streak has no information on its
    angle).
    """
    diag = np.diagonal(normal, axis1=1, axis2=2)
    return 1e-10 * np.sum(diag * scale * scale, axis=1, keepdims=True) / (scale * scale) + 1e-300


REWEIGHT_STEPS = 3  # linearizations whose model sets the weights (then they stay)
DECREMENT_TOLERANCE = 1e-3  # chi^2 still to gain: stop within ~3 % of a sigma of the minimum


class LeastSquaresModel(NamedTuple):
    """
    The model a batch fit solves (callables over the spots of one batch).

    evaluate(index, params (n, P)) -> aug (n, P + 1, M) float32: the jacobian (P rows) and the
    model [ADU] over the M window pixels of the spots `index` of the batch;
    max_step(params) -> (n, P) trust-region half-widths; constrain(index, params) -> params
    projected onto the feasible set; scale_of(params) -> (n, P) typical parameter units.
    """

    evaluate: Callable
    max_step: Callable
    constrain: Callable
    scale_of: Callable


class PixelNoise(NamedTuple):
    """Noise model of the pixels: variance max(model, 0) / gain + noise^2 [ADU^2]; noise [ADU], gain [e-/ADU]."""

    noise: float
    gain: float


class LeastSquaresSolution(NamedTuple):
    """
    params (N, P) at the solution.

    Fisher (N, P, P) the Fisher (Gauss-Newton) matrices there; done (N,) bool, a minimum was
    reached within the iterations; chi2 (N,) at the solution (inf where never evaluated).
    """

    params: np.ndarray
    fisher: np.ndarray
    done: np.ndarray
    chi2: np.ndarray


def levenberg_marquardt(model: LeastSquaresModel, params: np.ndarray, win: StreakWindows, valid: np.ndarray,
                        pixel_noise: PixelNoise, iterations: int) -> LeastSquaresSolution:
    """
    Weighted least squares by Levenberg-Marquardt, all spots at once (those still moving).

    Params (N, P) the start (overwritten), valid (N,) the spots to fit, at most `iterations`
    steps each.

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
    """
    state = _BatchState(params.shape, win, pixel_noise)
    n_par = params.shape[1]
    active = np.flatnonzero(valid)
    if active.size:
        aug = model.evaluate(active, params[active])
        state.linearize(active, aug, win.data[active] - aug[:, n_par])
        active = active[np.isfinite(state.chi2[active])]
    for _ in range(iterations):
        if active.size == 0:
            break
        active = state.iterate(model, params, active)
    return LeastSquaresSolution(params, state.normal, state.done, state.chi2)


class _BatchState:
    """
    The solver's per-spot state.

    Normal matrices N and gradients at the current parameters, chi^2, fixed weights, damping
    (lam, nu), the secant correction S.
    """

    def __init__(self, shape: tuple[int, int], win: StreakWindows, pixel_noise: PixelNoise) -> None:
        n, n_par = shape
        self.win, self.n_par = win, n_par
        self.noise2 = np.float32(pixel_noise.noise * pixel_noise.noise)
        self.inv_gain = np.float32(1.0 / pixel_noise.gain)
        self.normal = np.zeros((n, n_par, n_par))
        self.grad = np.zeros((n, n_par))
        self.chi2 = np.full(n, np.inf)
        self.weights = np.zeros_like(win.data)
        self.lam = np.full(n, 1e-3)
        self.nu = np.full(n, 2.0)
        self.done = np.zeros(n, bool)
        self.reweighted = np.zeros(n, np.int64)
        self.correction = np.zeros((n, n_par, n_par))  # S
        self.eye = np.eye(n_par)

    def linearize(self, index, aug, residual) -> None:
        """
        Return N, gradient and chi^2 of the spots `index`.

        From aug: the jacobian rows, then the model, replaced by the residual here.
        """
        n_par = self.n_par
        w = self.weights[index]
        fresh = self.reweighted[index] < REWEIGHT_STEPS
        if np.all(fresh):
            np.maximum(aug[:, n_par], 0.0, out=w)
            w *= self.inv_gain
            w += self.noise2
            np.divide(self.win.mask[index], w, out=w)
        elif np.any(fresh):
            w[fresh] = self.win.mask[index[fresh]] / (np.maximum(aug[fresh, n_par], 0.0) * self.inv_gain + self.noise2)
        self.reweighted[index] += 1
        aug[:, n_par] = residual
        weighted = aug * w[:, None, :]
        # One product gives the normal matrix and the gradient.
        products = np.matmul(weighted, aug.transpose(0, 2, 1)).astype(np.float64)
        self.weights[index] = w
        self.normal[index], self.grad[index] = products[:, :n_par, :n_par], products[:, :n_par, n_par]
        self.chi2[index] = _weighted_sum(weighted[:, n_par], residual)

    def iterate(self, model: LeastSquaresModel, params: np.ndarray, active: np.ndarray) -> np.ndarray:
        """One step for the spots `active` (params updated where chi^2 falls); returns the spots still moving."""
        p, g = params[active], self.grad[active]
        floor = _damping_floor(self.normal[active], model.scale_of(p))
        decrement = self._decrement(active, g, floor)
        a = self.normal[active] + self.correction[active]
        finished = ~(decrement > DECREMENT_TOLERANCE)  # NaN: give up
        self.done[active[finished & np.isfinite(decrement)]] = True
        keep = ~finished
        active, p, a, g, floor = active[keep], p[keep], a[keep], g[keep], floor[keep]
        if active.size == 0:
            return active
        diag = np.diagonal(a, axis1=1, axis2=2)
        damped = a + (self.lam[active, None] * diag + floor)[:, :, None] * self.eye
        step = _solve(damped, g)
        over = np.max(np.abs(step) / model.max_step(p), axis=1)
        step /= np.maximum(over, 1.0)[:, None]  # trust region, direction kept
        trial = model.constrain(active, p + step)
        finite = np.all(np.isfinite(trial), axis=1)
        trial = np.where(finite[:, None], trial, p)  # a failed solve: evaluated, never taken
        step = trial - p
        aug = model.evaluate(active, trial)
        r = self.win.data[active] - aug[:, self.n_par]
        trial_chi2 = _weighted_sum(self.weights[active] * r, r)
        old = self.chi2[active]
        actual = old - trial_chi2
        predicted = 2.0 * np.sum(step * g, axis=1) - np.einsum("ni,nij,nj->n", step, a, step)
        # The float32 model makes chi^2 uncertain by ~1e-3 for the brightest streaks: smaller
        # changes count as none (1e-3 in chi^2 is 3 % of a sigma).
        better = (actual >= -(1e-6 * old + 1e-3)) & finite
        ratio = actual / np.maximum(predicted, 1e-300)
        if np.any(better):
            self._accept(params, active, better, _Trial(trial, aug, r, step, a, g, predicted, ratio))
        return self._reject(active, active[~better])

    def _decrement(self, active, g, floor):
        """Return the Gauss-Newton decrement g^T N^-1 g of the spots `active` (the chi^2 still to gain)."""
        floored = self.normal[active] + floor[:, :, None] * self.eye
        return np.sum(_solve(floored, g) * g, axis=1)

    def _accept(self, params, active, better, trial: "_Trial") -> None:
        """Take the trial of the spots active[better]: relinearize, update S, relax damping."""
        idx = active[better]
        params[idx] = trial.params[better]
        # Measure curvature on steps with the same weights before and after, and large
        # enough that the gradient change stands above float32 rounding.
        frozen = (self.reweighted[idx] >= REWEIGHT_STEPS) & (trial.predicted[better] > 1e-2)
        if better.all():
            self.linearize(idx, trial.aug, trial.residual)
        else:
            self.linearize(idx, trial.aug[better], trial.residual[better])
        _secant_update(self.correction, idx[frozen], trial.step[better][frozen], trial.model_matrix[better][frozen],
                       trial.gradient[better][frozen] - self.grad[idx[frozen]])
        lam = self.lam
        lam[idx] *= np.maximum(1.0 / 3.0, 1.0 - (2.0 * np.clip(trial.ratio[better], 0.0, 1.0) - 1.0) ** 3)
        lam[idx] = np.maximum(lam[idx], 1e-9)
        self.nu[idx] = 2.0

    def _reject(self, active, worse) -> np.ndarray:
        """
        Raise the damping of the spots `worse` (no step taken).

        Returns the spots of `active` still moving (not stuck at a minimum to rounding).
        """
        self.lam[worse] *= self.nu[worse]
        self.nu[worse] *= 2.0
        stuck = worse[self.lam[worse] > 1e12]  # no step lowers chi^2: a minimum to rounding
        self.done[stuck] = True
        return active[~np.isin(active, stuck)]


class _Trial(NamedTuple):
    """
    A trial step of the active spots.

    Params, aug (their jacobian and model, the model row replaced by residual on linearizing),
    residual, step, model_matrix B = N + S, gradient, the predicted chi^2 decrease and its
    ratio to the actual one.
    """

    params: np.ndarray
    aug: np.ndarray
    residual: np.ndarray
    step: np.ndarray
    model_matrix: np.ndarray
    gradient: np.ndarray
    predicted: np.ndarray
    ratio: np.ndarray


def _weighted_sum(a, b):
    """Sum over pixels of a * b (float32), accumulated in float64."""
    return np.sum(a * b, axis=1, dtype=np.float64)


def _secant_update(correction, index, step, model_matrix, gradient_change) -> None:
    """
    Update S += (c - b) / b^2 (B step)(B step)^T with b = step^T B step.

    c = step^T (g_old - g_new) is the measured curvature along the step, clipped to [b / 4, 4
    b] (keeps B positive definite and a noisy measurement from flattening it).
    """
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
    """
    Inverse of the Fisher matrices (n, P, P).

    Degenerate directions floored (see _damping_floor): they come out with huge variance
    instead of failing the batch.
    """
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
