# SPDX-License-Identifier: Apache-2.0
"""
Joint fit of M pixel-integrated Gaussian PSFs per window, compiled (numba).

The blends' fit (gaussian_fit.fit_psf_windows with M > 1): one window per blend, too small
for numpy's per-call overhead. Gauss-Newton on (x_m, y_m, F_m) as gaussian_fit_kernel's with
M sources (test/centroid/gaussian_fit_reference.py is the same algorithm in numpy, the tests'
reference: results agree to ~1e-12 px).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .profile_kernel import gaussian_profile


@njit(cache=True, fastmath=False)
def _invert(a: np.ndarray, out: np.ndarray) -> bool:
    """Write the inverse of the square matrix `a` into `out` (Gauss-Jordan, partial pivoting); False if singular."""
    k = a.shape[0]
    work = a.copy()
    out[:, :] = 0.0
    for i in range(k):
        out[i, i] = 1.0
    for col in range(k):
        pivot = col
        for row in range(col + 1, k):
            if abs(work[row, col]) > abs(work[pivot, col]):
                pivot = row
        p = work[pivot, col]
        if not (p != 0.0 and math.isfinite(p)):
            return False
        if pivot != col:
            for j in range(k):
                work[col, j], work[pivot, j] = work[pivot, j], work[col, j]
                out[col, j], out[pivot, j] = out[pivot, j], out[col, j]
        for j in range(k):
            work[col, j] /= p
            out[col, j] /= p
        for row in range(k):
            if row != col:
                factor = work[row, col]
                if factor != 0.0:
                    for j in range(k):
                        work[row, j] -= factor * work[col, j]
                        out[row, j] -= factor * out[col, j]
    return True


@njit(cache=True, fastmath=False)
def fit_multi_psf(data, valid, col0, row0, x0, y0, flux0, sigma, noise, gain, iterations):
    """
    Fit M Gaussian PSFs (fixed sigma [px]) per window; the algorithm of gaussian_fit.fit_psf_windows.

    data float64, valid bool (n, S, S) [ADU, background subtracted]; col0, row0 (n,) the windows'
    top-left pixels; x0, y0, flux0 (n, M) the start. Weights 1 / (model / gain + noise^2);
    Gauss-Newton on (x_m, y_m, F_m) with a 1 px trust region and 1e-9 relative damping, a
    window stopping when every position step is below 1 % of its sigma. Returns x, y, flux
    (n, M), cov (n, M, 2, 2), flux_var (n, M), converged (n, M).
    """
    n, size, _ = data.shape
    m = x0.shape[1]
    p = 3 * m
    x, y = x0.copy(), y0.copy()
    flux = np.maximum(flux0.copy(), 1e-9)
    full = np.full((n, p, p), np.nan)
    px, dpx = np.empty((m, size)), np.empty((m, size))
    py, dpy = np.empty((m, size)), np.empty((m, size))
    normal = np.empty((p, p))
    inv = np.empty((p, p))
    grad = np.empty(p)
    jac = np.empty(p)
    step = np.empty(p)
    for s in range(n):
        for _ in range(iterations):
            for k in range(m):
                gaussian_profile(col0[s] - 0.5, x[s, k], sigma, size, px[k], dpx[k])
                gaussian_profile(row0[s] - 0.5, y[s, k], sigma, size, py[k], dpy[k])
            normal[:, :] = 0.0
            grad[:] = 0.0
            for i in range(size):
                for j in range(size):
                    if not valid[s, i, j]:
                        continue
                    model = 0.0
                    for k in range(m):
                        shape = py[k, i] * px[k, j]
                        model += flux[s, k] * shape
                        jac[3 * k] = flux[s, k] * py[k, i] * dpx[k, j]
                        jac[3 * k + 1] = flux[s, k] * dpy[k, i] * px[k, j]
                        jac[3 * k + 2] = shape
                    weight = 1.0 / (max(model, 0.0) / gain + noise * noise)
                    resid = data[s, i, j] - model
                    for a in range(p):
                        wa = weight * jac[a]
                        grad[a] += wa * resid
                        for b in range(a, p):
                            normal[a, b] += wa * jac[b]
            for a in range(p):
                for b in range(a):
                    normal[a, b] = normal[b, a]
                normal[a, a] += 1e-9 * abs(normal[a, a]) + 1e-300
            if not _invert(normal, inv):
                inv[:, :] = np.nan  # as the numpy path: the window stops, not converged
            full[s] = inv
            for a in range(p):
                total = 0.0
                for b in range(p):
                    total += inv[a, b] * grad[b]
                step[a] = total
            moving = False
            for k in range(m):
                step_x = min(max(step[3 * k], -1.0), 1.0)  # trust region: 1 px per step
                step_y = min(max(step[3 * k + 1], -1.0), 1.0)
                x[s, k] += step_x
                y[s, k] += step_y
                flux[s, k] = max(flux[s, k] + step[3 * k + 2], 1e-9)
                if (step_x * step_x > max(1e-4 * abs(inv[3 * k, 3 * k]), 1e-10)
                        or step_y * step_y > max(1e-4 * abs(inv[3 * k + 1, 3 * k + 1]), 1e-10)):
                    moving = True
            if not moving:
                break
    cov = np.empty((n, m, 2, 2))
    flux_var = np.empty((n, m))
    converged = np.zeros((n, m), np.bool_)
    for s in range(n):
        for k in range(m):
            c = 3 * k
            cov[s, k, 0, 0], cov[s, k, 0, 1] = full[s, c, c], full[s, c, c + 1]
            cov[s, k, 1, 0], cov[s, k, 1, 1] = full[s, c + 1, c], full[s, c + 1, c + 1]
            flux_var[s, k] = full[s, c + 2, c + 2]
            converged[s, k] = (math.isfinite(cov[s, k, 0, 0]) and math.isfinite(cov[s, k, 0, 1])
                               and math.isfinite(cov[s, k, 1, 0]) and math.isfinite(cov[s, k, 1, 1])
                               and cov[s, k, 0, 0] > 0 and cov[s, k, 1, 1] > 0
                               and math.isfinite(x[s, k]) and math.isfinite(y[s, k])
                               and col0[s] + 0.5 < x[s, k] < col0[s] + size - 1.5
                               and row0[s] + 0.5 < y[s, k] < row0[s] + size - 1.5)
    return x, y, flux, cov, flux_var, converged


def warm_up() -> None:
    """Compile (or load from the cache) the fit for the float64 windows gaussian_fit passes."""
    data = np.zeros((1, 7, 7))
    data[0, 3, 3] = 100.0
    pair = np.full((1, 2), 3.0)
    fit_multi_psf(data, np.ones((1, 7, 7), np.bool_), np.zeros(1), np.zeros(1), pair, pair, pair * 30.0, 1.0, 1.0,
                  1.0, 2)
