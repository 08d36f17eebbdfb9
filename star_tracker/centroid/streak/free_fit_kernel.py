# SPDX-License-Identifier: Apache-2.0
"""
The free straight-streak fit, compiled (numba): Levenberg-Marquardt on the segment model, one spot at a time.

The algorithm of levenberg_marquardt.levenberg_marquardt (weights, secant correction,
Nielsen damping, damping floor, Gauss-Newton decrement stop, trust region, acceptance test)
with streak.free_fit's segment model, in float64. Why compiled: a spot's step costs tens of
microseconds, while the batched numpy solver paid ~0.5 ms of fixed overhead per step
whatever the batch size (~16 ms for 19 elongated spots over 30 steps).

Model of a spot (parameters x, y [px, image frame], F [ADU], L [px], theta [rad from +x
toward +y]): F times the Gaussian of variance sigma^2 + 1/12 px^2 (the pixel-integrated PSF to
second order; streak.model's docstring) averaged along the segment of length L at angle
theta centred on (x, y), by Simpson's rule on nodes about 1 PSF sigma apart, evaluated at
the pixel centres of the spot's window. Pixel (0, 0) is the centre of the top-left pixel.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .model import PIXEL_VARIANCE
from .narrow_width import NARROW_PX

NODE_SPACING_SIGMA = 1.0  # Simpson nodes along the segment this far apart [PSF sigma]
N_PAR = 5  # x, y, F, L, theta
_NARROW_VARIANCE = NARROW_PX * NARROW_PX  # a PSF variance below this gets the exact pixel integral [px^2]
_EXPONENT_FLOOR = 30.0  # exp(-30) ~ 1e-13: the profiles' floor, as streak.model._profiles
_FLOOR = math.exp(-_EXPONENT_FLOOR)
# The pixel loops may sum in any order and fuse multiply-adds (so they vectorize), with no
# assumption on NaN or inf (a failed model must still come out NaN).
_PIXEL_LOOPS = {"reassoc", "contract"}
_START_DAMPING = 1e-3  # Levenberg-Marquardt's first lambda (relative to the diagonal)
_MIN_DAMPING, _MAX_DAMPING = 1e-9, 1e12  # lambda's floor; above the ceiling no step lowers chi^2


class FreeFitSettings(NamedTuple):
    """
    How fit_segments fits.

    sigma: PSF 1-sigma [px]; noise: 1-sigma pixel noise [ADU]; gain [e-/ADU]; iterations:
    at most this many Levenberg-Marquardt steps per spot; reweight_steps, decrement_tolerance:
    levenberg_marquardt's REWEIGHT_STEPS and DECREMENT_TOLERANCE (passed, not imported: a
    cached kernel would not see a change of another module's constants).
    """

    sigma: float
    noise: float
    gain: float
    iterations: int
    reweight_steps: int
    decrement_tolerance: float


class FreeFitSolution(NamedTuple):
    """
    fit_segments' result per spot (n,).

    params (n, 5) (x, y [px], F [ADU], L [px], theta [rad]) at the solution (the start where
    nothing was fitted); fisher (n, 5, 5) the Gauss-Newton (Fisher) matrices there (zero where
    nothing was fitted); done (n,) bool, a minimum was reached within the iterations; chi2
    (n,) at the solution (inf where never evaluated); steps (n,) the trial steps taken
    (accepted or not).
    """

    params: np.ndarray
    fisher: np.ndarray
    done: np.ndarray
    chi2: np.ndarray
    steps: np.ndarray


def fit_segments(data: np.ndarray, mask: np.ndarray, origin: np.ndarray, size: np.ndarray, start: np.ndarray,
                 max_length: np.ndarray, valid: np.ndarray, settings: FreeFitSettings) -> FreeFitSolution:
    """
    Fit the segment model (module docstring) to each spot's window.

    data, mask: (n, R, C) float32 windows padded to one size (streak.model.cut_windows:
    data [ADU], 0 where masked; mask 1 = use); origin (n, 2) float64 the image pixel (col, row) of
    each window's first element [px]; size (n, 2) int64 the rows and columns of each spot's own
    window (the rest is padding); start (n, 5) float64 the starting parameters; max_length (n,)
    [px] the longest segment that fits the window (L is capped at twice it); valid (n,) bool
    the spots to fit; settings: FreeFitSettings.
    """
    return FreeFitSolution(*_fit_segments(data, mask, origin, size, start, max_length, valid, settings))


@njit(cache=True, error_model="numpy")
def _even_intervals(count: float) -> int:
    """Smallest even integer >= count (at least 2): a Simpson interval count."""
    n = max(int(math.ceil(count)), 2)
    return n + n % 2


@njit(cache=True, error_model="numpy")
def _fit_segments(data, mask, origin, size, start, max_length, valid, settings):
    """Compute fit_segments (compiled): returns its FreeFitSolution's arrays."""
    n = data.shape[0]
    var_eff = settings.sigma * settings.sigma + PIXEL_VARIANCE
    node_spacing = NODE_SPACING_SIGMA * math.sqrt(var_eff)
    params = start.copy()
    fisher = np.zeros((n, N_PAR, N_PAR))
    done = np.zeros(n, np.bool_)
    chi2 = np.full(n, np.inf)
    steps = np.zeros(n, np.int64)
    # Work arrays for the largest node count any spot can reach (L <= 2 max_length).
    nodes = 1
    for s in range(n):
        if valid[s]:
            nodes = max(nodes, _even_intervals(1.2 * (2.0 * max_length[s]) / node_spacing) + 1)
    n_rows, n_cols = data.shape[1], data.shape[2]
    work = _Work(np.empty((nodes, n_cols)), np.empty((nodes, n_cols)), np.empty((nodes, n_rows)),
                 np.empty((nodes, n_rows)), np.empty(nodes), np.empty((5, n_cols)),
                 np.empty((N_PAR + 1, n_rows, n_cols)), np.empty((n_rows, n_cols)), np.empty(n_cols), np.empty(n_cols),
                 _gaussian_table(1.0 / math.sqrt(2.0 * var_eff)))
    for s in range(n):
        if valid[s]:
            done[s], chi2[s], steps[s] = _fit_spot(data[s], mask[s], origin[s, 0], origin[s, 1], size[s, 0],
                                                   size[s, 1], params[s], max_length[s], fisher[s], settings, work)
    return params, fisher, done, chi2, steps


class _Work(NamedTuple):
    """
    Work arrays of the model (K nodes, window R x C).

    gx, vgx (K, C) and gy, vgy (K, R): the nodes' Gaussian profiles g and v g across the
    columns and rows (gy carries the Simpson weights); lever (K,) the nodes' positions along
    the segment in [-1/2, 1/2]; sums (5, C) one row's sums over nodes; aug (6, R, C) the
    jacobian (x, y, F, L, theta) and the model [ADU]; weights (R, C) [1/ADU^2]; residual,
    weighted (C,) one row's residuals [ADU] and weighted jacobian row; table: _gaussian_table.
    """

    gx: np.ndarray
    vgx: np.ndarray
    gy: np.ndarray
    vgy: np.ndarray
    lever: np.ndarray
    sums: np.ndarray
    aug: np.ndarray
    weights: np.ndarray
    residual: np.ndarray
    weighted: np.ndarray
    table: np.ndarray


@njit(cache=True, error_model="numpy")
def _fit_spot(data, mask, col0, row0, rows, cols, p, max_length, normal, settings, work):
    """
    Levenberg-Marquardt on one spot's window (rows x cols of data, mask; top-left pixel (col0, row0) [px]).

    p (5,) the start, overwritten by the solution; max_length [px]: L is capped at twice it;
    normal (5, 5) receives the Fisher matrix at the solution. Returns (done, chi2, trial
    steps). As levenberg_marquardt.levenberg_marquardt: weights from the model for the first
    settings.reweight_steps linearizations, then fixed; steps from B = N + S (S the secant
    correction) damped by Nielsen's rule; stop when the Gauss-Newton decrement is below
    settings.decrement_tolerance, or when no step lowers chi^2.
    """
    var_eff = settings.sigma * settings.sigma + PIXEL_VARIANCE
    scale = 1.0 / math.sqrt(2.0 * var_eff)
    node_spacing = NODE_SPACING_SIGMA * math.sqrt(var_eff)
    noise2 = settings.noise * settings.noise
    grad, old_grad, floor = np.zeros(N_PAR), np.empty(N_PAR), np.empty(N_PAR)
    trial, step, b_step = np.empty(N_PAR), np.empty(N_PAR), np.empty(N_PAR)
    model_matrix = np.empty((N_PAR, N_PAR))  # B
    correction = np.zeros((N_PAR, N_PAR))  # S
    linear = _LinearWork(np.empty((N_PAR, N_PAR)), np.empty((N_PAR, N_PAR)), np.empty(N_PAR), np.empty(N_PAR))
    # Nodes: a fixed count keeps the model a smooth function of L (a count following L would
    # change the model in steps the acceptance test sees as noise); it grows, once in a
    # while, only when L outgrows the node spacing.
    intervals = _even_intervals(1.2 * p[3] / node_spacing)
    _segment_model(p, col0, row0, rows, cols, intervals, scale, work)
    _segment_jacobian(p, rows, cols, intervals, scale, work)
    reweighted = 0  # linearizations so far: the first settings.reweight_steps set the weights
    chi2 = _linearize(data, mask, rows, cols, reweighted < settings.reweight_steps, noise2, settings.gain, normal,
                      grad, work)
    reweighted += 1
    if not math.isfinite(chi2):
        return False, chi2, 0
    lam, nu = _START_DAMPING, 2.0
    steps = 0
    for _ in range(settings.iterations):
        _damping_floor(normal, max(abs(p[2]), settings.noise), floor)
        decrement, unresolved = _decrement(normal, grad, floor, p[3], linear)
        if not decrement > settings.decrement_tolerance:  # NaN: give up
            return math.isfinite(decrement), chi2, steps
        model_matrix[:, :] = normal + correction
        finite = _trial_step(model_matrix, grad, floor, lam, unresolved, p, max_length, trial, linear)
        step[:] = trial - p
        steps += 1
        trial_chi2 = np.nan
        if finite:
            if _even_intervals(trial[3] / node_spacing) > intervals:
                intervals = _even_intervals(1.2 * trial[3] / node_spacing)
            _segment_model(trial, col0, row0, rows, cols, intervals, scale, work)
            trial_chi2 = _weighted_chi2(data, rows, cols, work)
        actual = chi2 - trial_chi2
        predicted = 0.0  # 2 step^T g - step^T B step
        for i in range(N_PAR):
            b_step[i] = _dot(model_matrix[i], step)
            predicted += step[i] * (2.0 * grad[i] - b_step[i])
        # The float32 model of the numpy solver made chi^2 uncertain by ~1e-3 for the
        # brightest streaks: smaller changes count as none (1e-3 in chi^2 is 3 % of a sigma).
        if finite and actual >= -(1e-6 * chi2 + 1e-3):
            gain_ratio = actual / _maximum(predicted, 1e-300)
            # Measure curvature on steps with the same weights before and after, and large
            # enough that the gradient change stands above rounding.
            frozen = reweighted >= settings.reweight_steps and predicted > 1e-2
            p[:] = trial
            old_grad[:] = grad
            _segment_jacobian(p, rows, cols, intervals, scale, work)
            chi2 = _linearize(data, mask, rows, cols, reweighted < settings.reweight_steps, noise2, settings.gain,
                              normal, grad, work)
            reweighted += 1
            if frozen:
                _secant_update(correction, step, b_step, old_grad, grad)
            clipped = _minimum(_maximum(gain_ratio, 0.0), 1.0)
            lam = _maximum(lam * _maximum(1.0 / 3.0, 1.0 - (2.0 * clipped - 1.0) ** 3), _MIN_DAMPING)
            nu = 2.0
        else:
            lam *= nu
            nu *= 2.0
            if lam > _MAX_DAMPING:  # no step lowers chi^2: a minimum to rounding
                return True, chi2, steps
    return False, chi2, steps


class _LinearWork(NamedTuple):
    """Work arrays of the 5 x 5 solves: system, lu (5, 5); rhs, solution (5,)."""

    system: np.ndarray
    lu: np.ndarray
    rhs: np.ndarray
    solution: np.ndarray


@njit(cache=True, error_model="numpy")
def _decrement(normal, grad, floor, length, linear):
    """
    Return the Gauss-Newton decrement g^T N^-1 g (the chi^2 still to gain; NaN: singular) and whether unresolved.

    N floored (floor (5,)); an unresolved streak's L and theta are left out (_unresolved).
    """
    system, rhs, solution = linear.system, linear.rhs, linear.solution
    system[:, :] = normal
    for i in range(N_PAR):
        system[i, i] += floor[i]
        rhs[i] = 0.0
    rhs[3] = 1.0
    variance_length = solution[3] if _solve(system, rhs, solution, linear.lu) else np.nan
    unresolved = _unresolved(length, variance_length)
    rhs[:] = grad
    if unresolved:
        _hold(system, rhs, 3)
        _hold(system, rhs, 4)
    if not _solve(system, rhs, solution, linear.lu):
        return np.nan, unresolved
    return _dot(solution, rhs), unresolved


@njit(cache=True, error_model="numpy")
def _trial_step(model_matrix, grad, floor, lam, unresolved, p, max_length, trial, linear):
    """
    Write the trial parameters of a damped step from p into trial; return False (trial = p) for a failed solve.

    (B + lam diag(B) + diag(floor)) step = g, theta held when unresolved; the step scaled into
    the trust region (1 px, none for F (linear), max(2 px, L / 2), 0.3 rad), its direction
    kept; then |L| capped at 2 max_length (the model is even in L; the cap, flagged by the
    caller, bounds the nodes of a runaway fit).
    """
    system, rhs, step = linear.system, linear.rhs, linear.solution
    system[:, :] = model_matrix
    for i in range(N_PAR):
        system[i, i] += lam * model_matrix[i, i] + floor[i]
    rhs[:] = grad
    if unresolved:  # a free direction would take the whole trust region
        _hold(system, rhs, 4)
    if not _solve(system, rhs, step, linear.lu):
        step[:] = np.nan
    limits = (1.0, 1.0, np.inf, max(2.0, 0.5 * p[3]), 0.3)
    over = 0.0  # the largest |step| / limit, NaN if any is
    for i in range(N_PAR):
        over = _maximum(over, abs(step[i]) / limits[i])
    trial[:] = p + step / _maximum(over, 1.0)
    if not math.isnan(trial[3]):
        trial[3] = min(abs(trial[3]), 2.0 * max_length)
    if np.all(np.isfinite(trial)):
        return True
    trial[:] = p  # never taken (nor evaluated)
    return False


@njit(cache=True, error_model="numpy", fastmath=_PIXEL_LOOPS)
def _segment_model(p, col0, row0, rows, cols, intervals, scale, work):
    """
    Write the model [ADU] of parameters p and its derivative by F into work.aug (rows 5 and 2).

    Over the rows x cols pixels of the window whose top-left pixel is (col0, row0) [px];
    Simpson's rule with `intervals` (even) intervals; scale = 1 / sqrt(2 var_eff) [1/px].
    Each node's PSF copy is separable: a pixel's sums over nodes are of g_y g_x products
    (streak.model.sample_sums), with g = exp(-min(v^2, 30)), v = (pixel - node) scale. The
    nodes' profiles stay in work for _segment_jacobian.
    """
    gx, gy, lever, aug = work.gx, work.gy, work.lever, work.aug
    xc, yc, flux, length, theta = p[0], p[1], p[2], p[3], p[4]
    ct, st = math.cos(theta), math.sin(theta)
    count = intervals
    for k in range(count + 1):
        s = k / count - 0.5
        weight = (1.0 if k == 0 or k == count else (4.0 if k % 2 == 1 else 2.0)) / (3.0 * count)
        lever[k] = s
        _profile((xc - col0) + length * ct * s, scale, 1.0, cols, work.table, gx[k], work.vgx[k])
        _profile((yc - row0) + length * st * s, scale, weight, rows, work.table, gy[k], work.vgy[k])
    amplitude_unit = scale * scale / math.pi  # peak of the unit-flux Gaussian, 1 / (2 pi var_eff)
    a = flux * amplitude_unit
    shape = work.sums[0]
    for r in range(rows):
        shape[:cols] = 0.0
        for k in range(count + 1):
            g_y, g_x = gy[k, r], gx[k]
            for c in range(cols):
                shape[c] += g_y * g_x[c]
        d_flux, model = aug[2, r], aug[N_PAR, r]
        for c in range(cols):
            d_flux[c] = amplitude_unit * shape[c]
            model[c] = a * shape[c]


@njit(cache=True, error_model="numpy", fastmath=_PIXEL_LOOPS)
def _segment_jacobian(p, rows, cols, intervals, scale, work):
    """
    Write the derivatives by x, y, L and theta of the model at p into work.aug (rows 0, 1, 3, 4).

    From the profiles _segment_model left in work for the same p (a trial step's model is
    all its acceptance test needs: the jacobian only for the steps taken).
    """
    gx, vgx, gy, vgy, lever, sums, aug = work.gx, work.vgx, work.gy, work.vgy, work.lever, work.sums, work.aug
    flux, length, theta = p[2], p[3], p[4]
    ct, st = math.cos(theta), math.sin(theta)
    b = flux * (scale * scale / math.pi) * (2.0 * scale)  # d/d(node position) of the unnormalized profiles
    bl = b * length
    gx_d, gy_d, s_gy_d, s_gx_d = sums[1], sums[2], sums[3], sums[4]
    for r in range(rows):
        sums[1:, :cols] = 0.0
        # One loop per column profile: few arrays per loop, so that it vectorizes.
        for k in range(intervals + 1):
            g_y, vg_y = gy[k, r], vgy[k, r]
            s_vg_y, s_g_y = lever[k] * vg_y, lever[k] * g_y
            g_x = gx[k]
            for c in range(cols):
                gy_d[c] += vg_y * g_x[c]
                s_gy_d[c] += s_vg_y * g_x[c]
            vg_x = vgx[k]
            for c in range(cols):
                gx_d[c] += g_y * vg_x[c]
                s_gx_d[c] += s_g_y * vg_x[c]
        d_x, d_y, d_length, d_theta = aug[0, r], aug[1, r], aug[3, r], aug[4, r]
        for c in range(cols):
            d_x[c] = b * gx_d[c]
            d_y[c] = b * gy_d[c]
            d_length[c] = b * st * s_gy_d[c] + b * ct * s_gx_d[c]  # along the streak, growing with s
            d_theta[c] = bl * ct * s_gy_d[c] - bl * st * s_gx_d[c]  # across it, growing with s


@njit(cache=True, error_model="numpy")
def _profile(centre, scale, weight, count, table, g, vg):
    """
    Write a node's Gaussian profile over the pixel centres 0..count-1 of a window row or column.

    g = weight exp(-min(v^2, 30)) and vg = v g with v = (pixel - centre) scale; the floor
    exp(-30) ~ 1e-13 as streak.model._profiles. table: _gaussian_table(scale). Why not exp
    per pixel: that was half the model's cost. With m the pixel nearest the centre, f =
    centre - m and d = pixel - m, exp(-v^2) = table[|d|] b^d exp(-f^2 scale^2), b = exp(2 f
    scale^2): two exp per node, the powers of b by products (~1e-14 off at most).
    """
    floor = weight * _FLOOR
    if 0.5 / (scale * scale) - PIXEL_VARIANCE < _NARROW_VARIANCE:
        _integrated_profile(centre, scale, weight, count, g, vg)
        return
    nearest = round(centre)
    f = centre - nearest
    scale2 = scale * scale
    factor = math.exp(2.0 * f * scale2)
    power = 0.0  # weight exp(-f^2 scale^2) b^d, from the first pixel inside the band (where v^2 < 30) on
    inside = False
    for i in range(count):
        v = (i - centre) * scale
        d = i - nearest
        if v * v >= _EXPONENT_FLOOR:
            value = floor
        else:
            if inside:
                power *= factor
            else:
                power = weight * math.exp(2.0 * d * f * scale2 - f * f * scale2)
                inside = True
            value = table[abs(d)] * power
        g[i] = value
        vg[i] = v * value


@njit(cache=True, error_model="numpy")
def _integrated_profile(centre, scale, weight, count, g, vg):
    """
    Write _profile's g and v g for a PSF narrower than narrow_width.NARROW_PX: the Gaussian integrated over each pixel.

    As streak.model._integrated_profiles: g = weight sqrt(pi) / scale (Phi(u+) - Phi(u-)), u+-
    = (pixel +- 1/2 - centre) / sigma, and v g = (dg/dcentre) / (2 scale); floored as _profile.
    """
    sigma = math.sqrt(max(0.5 / (scale * scale) - PIXEL_VARIANCE, 1e-6))
    norm = weight * math.sqrt(math.pi) / scale
    floor = weight * _FLOOR
    root2 = math.sqrt(2.0)
    density = 1.0 / (math.sqrt(2.0 * math.pi) * sigma)
    for i in range(count):
        upper = (i - centre + 0.5) / sigma
        lower = (i - centre - 0.5) / sigma
        share = norm * 0.5 * (math.erf(upper / root2) - math.erf(lower / root2))
        g[i] = share if share > floor else floor
        vg[i] = norm * density * (math.exp(-0.5 * lower * lower) - math.exp(-0.5 * upper * upper)) / (2.0 * scale)


@njit(cache=True, error_model="numpy")
def _gaussian_table(scale):
    """exp(-(d scale)^2) for the integers d >= 0 inside the floor's band (v^2 < 30), for _profile."""
    table = np.empty(int(math.sqrt(_EXPONENT_FLOOR) / scale) + 2)
    for d in range(table.size):
        table[d] = math.exp(-(d * scale) ** 2)
    return table


@njit(cache=True, error_model="numpy", fastmath=_PIXEL_LOOPS)
def _linearize(data, mask, rows, cols, reweight, noise2, gain, normal, grad, work):
    """
    Return chi^2, and write the normal matrix and gradient, at the model and jacobian in work.aug (rows x cols pixels).

    With `reweight`, work.weights first become mask / (max(model, 0) / gain + noise2); normal
    (5, 5) and grad (5,) are overwritten.
    """
    aug, weights, residual, weighted = work.aug, work.weights, work.residual, work.weighted
    normal[:, :] = 0.0
    grad[:] = 0.0
    chi2 = 0.0
    for r in range(rows):
        model, w, pixels, use = aug[N_PAR, r], weights[r], data[r], mask[r]
        if reweight:
            for c in range(cols):
                w[c] = use[c] / (_maximum(model[c], 0.0) / gain + noise2)
        for c in range(cols):
            residual[c] = pixels[c] - model[c]
        # Row by row, one sum per loop: they vectorize.
        for i in range(N_PAR):
            jac = aug[i, r]
            for c in range(cols):
                weighted[c] = w[c] * jac[c]
            total = 0.0
            for c in range(cols):
                total += weighted[c] * residual[c]
            grad[i] += total
            for j in range(i, N_PAR):
                other = aug[j, r]
                total = 0.0
                for c in range(cols):
                    total += weighted[c] * other[c]
                normal[i, j] += total
        total = 0.0
        for c in range(cols):
            total += w[c] * residual[c] * residual[c]
        chi2 += total
    for i in range(N_PAR):
        for j in range(i):
            normal[i, j] = normal[j, i]
    return chi2


@njit(cache=True, error_model="numpy", fastmath=_PIXEL_LOOPS)
def _weighted_chi2(data, rows, cols, work):
    """Chi^2 of the model in work.aug with the current work.weights (rows x cols pixels)."""
    aug, weights = work.aug, work.weights
    chi2 = 0.0
    for r in range(rows):
        model, w, pixels = aug[N_PAR, r], weights[r], data[r]
        total = 0.0
        for c in range(cols):
            residual = pixels[c] - model[c]
            total += w[c] * residual * residual
        chi2 += total
    return chi2


@njit(cache=True, error_model="numpy")
def _damping_floor(normal, flux_unit, floor):
    """
    1e-10 of the total information per parameter, in typical units (1 px, 1 rad, flux_unit [ADU]), into floor.

    As levenberg_marquardt._damping_floor: keeps degenerate systems solvable (a zero-length
    streak has no information on its angle).
    """
    total = 0.0
    for i in range(N_PAR):
        unit = flux_unit if i == 2 else 1.0
        total += normal[i, i] * unit * unit
    for i in range(N_PAR):
        unit = flux_unit if i == 2 else 1.0
        floor[i] = 1e-10 * total / (unit * unit) + 1e-300


@njit(cache=True, error_model="numpy")
def _unresolved(length, variance_length):
    """
    Return whether the streak is unresolved: L < 2 sigma_L (variance_length [px^2], NaN: no).

    The model is even in L, so near L = 0 the chi^2 still to gain in L and theta stays at
    the noise level, ~1, however small L gets; (x, y, F) decouple from them: convergence is
    judged on (x, y, F). Theta is held (it would wander by the trust region and shrink every
    step with it); L stays free to grow if the spot is a streak after all.
    """
    return length < 2.0 * math.sqrt(_maximum(variance_length, 0.0))


@njit(cache=True, error_model="numpy")
def _hold(matrix, rhs, i):
    """Take parameter i out of the system matrix x = rhs: its row and column of the identity, rhs 0."""
    for j in range(N_PAR):
        matrix[i, j] = 0.0
        matrix[j, i] = 0.0
    matrix[i, i] = 1.0
    rhs[i] = 0.0


@njit(cache=True, error_model="numpy")
def _secant_update(correction, step, b_step, old_grad, new_grad):
    """
    S += (c - b) / b^2 (B step)(B step)^T with b = step^T B step (b_step = B step).

    c = step^T (g_old - g_new) is the measured curvature along the step, clipped to [b / 4,
    4 b] (keeps B positive definite and a noisy measurement from flattening it).
    """
    b = 0.0
    c = 0.0
    for i in range(N_PAR):
        b += step[i] * b_step[i]
        c += step[i] * (old_grad[i] - new_grad[i])
    if not b > 0.0:
        return
    c = _minimum(_maximum(c, 0.25 * b), 4.0 * b)
    alpha = (c - b) / (b * b)
    for i in range(N_PAR):
        for j in range(N_PAR):
            correction[i, j] += alpha * b_step[i] * b_step[j]


@njit(cache=True, error_model="numpy")
def _solve(matrix, rhs, out, lu):
    """
    Solve matrix out = rhs by LU with partial pivoting (as numpy.linalg.solve); matrix and rhs are kept.

    False (out undefined) when a pivot is exactly 0: numpy's LinAlgError, a NaN step.
    """
    n = rhs.size
    lu[:, :] = matrix
    out[:] = rhs
    for j in range(n):
        pivot, largest = j, abs(lu[j, j])
        for i in range(j + 1, n):
            if abs(lu[i, j]) > largest:
                pivot, largest = i, abs(lu[i, j])
        if largest == 0.0:
            return False
        if pivot != j:
            for k in range(n):
                lu[j, k], lu[pivot, k] = lu[pivot, k], lu[j, k]
            out[j], out[pivot] = out[pivot], out[j]
        for i in range(j + 1, n):
            factor = lu[i, j] / lu[j, j]
            for k in range(j + 1, n):
                lu[i, k] -= factor * lu[j, k]
            out[i] -= factor * out[j]
    for i in range(n - 1, -1, -1):
        v = out[i]
        for k in range(i + 1, n):
            v -= lu[i, k] * out[k]
        out[i] = v / lu[i, i]
    return True


@njit(cache=True, error_model="numpy")
def _dot(a, b):
    """Sum of a * b over two vectors of the same size."""
    total = 0.0
    for i in range(a.size):
        total += a[i] * b[i]
    return total


@njit(cache=True, error_model="numpy")
def _maximum(a, b):
    """numpy.maximum of two floats: NaN if either is."""
    return a if (a >= b or math.isnan(a)) else b


@njit(cache=True, error_model="numpy")
def _minimum(a, b):
    """numpy.minimum of two floats: NaN if either is."""
    return a if (a <= b or math.isnan(a)) else b


def warm_up() -> None:
    """Compile (or load from the cache) the fit for the float32 windows free_fit cuts (model.cut_windows)."""
    rows, cols = 8, 20
    data = np.zeros((1, rows, cols), np.float32)
    data[0, 4, 6:14] = 100.0
    start = np.array([[10.0, 4.0, 800.0, 8.0, 0.0]])
    fit_segments(data, np.ones((1, rows, cols), np.float32), np.zeros((1, 2)), np.array([[rows, cols]], np.int64),
                 start, np.full(1, 21.0), np.ones(1, np.bool_), FreeFitSettings(1.0, 1.0, 1.0, 2, 3, 1e-6))
