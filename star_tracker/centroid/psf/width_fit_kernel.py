# SPDX-License-Identifier: Apache-2.0
"""One pixel-integrated circular Gaussian per window with a free width, compiled (numba): the PSF estimate's fit."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .matrix_kernel import solve_spd
from .profile_kernel import gaussian_profile_with_width


@njit(cache=True, fastmath=False)
def fit_psf_width(data, valid, col0, row0, x0, y0, flux0, sigma0, noise, gain, iterations):
    """
    One pixel-integrated circular Gaussian per window with free width and a constant background offset.

    Parameters (x, y [px], flux [ADU], sigma [px], offset [ADU]) by weighted Gauss-Newton
    (weights 1 / (star model / gain + noise^2)), 1 px trust region on the centre, sigma kept in
    [0.1, 12] px and changed by at most half of itself per step; converged when a step moves
    the centre < 0.01 px and sigma < 0.2 % (the estimate is a median over stars). data (n, S,
    S) background-subtracted windows [ADU], valid (n, S, S) bool, col0/row0 (n,) top-left
    pixels [px]; starts x0, y0, flux0, sigma0 (n,). Returns x, y, flux, sigma (n,), sigma_var
    (n,) [px^2] (inverse Fisher information), chi2 (n,) (reduced: per degree of freedom),
    converged (n,), offset (n,) [ADU] (the background the windows still hold).
    """
    n, size, _ = data.shape
    x, y, flux, sigma = x0.copy(), y0.copy(), np.maximum(flux0.copy(), 1e-9), sigma0.copy()
    offset = np.zeros(n)
    sigma_var = np.full(n, np.nan)
    chi2 = np.full(n, np.nan)
    converged = np.zeros(n, np.bool_)
    px, dpx, spx = np.empty(size), np.empty(size), np.empty(size)
    py, dpy, spy = np.empty(size), np.empty(size), np.empty(size)
    normal, work = np.empty((5, 5)), np.empty((5, 5))
    grad, jac, step, unit = np.empty(5), np.empty(5), np.empty(5), np.empty(5)
    for s in range(n):
        done = False
        for _ in range(iterations):
            gaussian_profile_with_width(col0[s] - 0.5, x[s], sigma[s], size, px, dpx, spx)
            gaussian_profile_with_width(row0[s] - 0.5, y[s], sigma[s], size, py, dpy, spy)
            normal[:, :] = 0.0
            grad[:] = 0.0
            f = flux[s]
            for i in range(size):
                for j in range(size):
                    if not valid[s, i, j]:
                        continue
                    star = f * py[i] * px[j]
                    weight = 1.0 / (max(star, 0.0) / gain + noise * noise)
                    jac[0] = f * py[i] * dpx[j]
                    jac[1] = f * dpy[i] * px[j]
                    jac[2] = py[i] * px[j]
                    jac[3] = f * (spy[i] * px[j] + py[i] * spx[j])
                    jac[4] = 1.0
                    resid = data[s, i, j] - star - offset[s]
                    for a in range(5):
                        wa = weight * jac[a]
                        grad[a] += wa * resid
                        for b in range(a, 5):
                            normal[a, b] += wa * jac[b]
            for a in range(5):
                for b in range(a):
                    normal[a, b] = normal[b, a]
                normal[a, a] += 1e-9 * abs(normal[a, a]) + 1e-300
            work[:, :] = normal
            if not solve_spd(work, grad, step):
                break
            step[0] = min(max(step[0], -1.0), 1.0)
            step[1] = min(max(step[1], -1.0), 1.0)
            step[3] = min(max(step[3], -0.5 * sigma[s]), 0.5 * sigma[s])
            x[s] += step[0]
            y[s] += step[1]
            flux[s] = max(flux[s] + step[2], 1e-9)
            sigma[s] = min(max(sigma[s] + step[3], 0.1), 12.0)
            offset[s] += step[4]
            if abs(step[0]) < 1e-2 and abs(step[1]) < 1e-2 and abs(step[3]) < 2e-3 * sigma[s]:
                done = True
                break
        if not done:
            continue
        # The width's variance: the (sigma, sigma) element of the inverse information.
        work[:, :] = normal
        unit[:] = 0.0
        unit[3] = 1.0
        if not solve_spd(work, unit, step):
            continue
        sigma_var[s] = step[3]
        gaussian_profile_with_width(col0[s] - 0.5, x[s], sigma[s], size, px, dpx, spx)
        gaussian_profile_with_width(row0[s] - 0.5, y[s], sigma[s], size, py, dpy, spy)
        total, count = 0.0, 0
        for i in range(size):
            for j in range(size):
                if valid[s, i, j]:
                    star = flux[s] * py[i] * px[j]
                    resid = data[s, i, j] - star - offset[s]
                    total += resid * resid / (max(star, 0.0) / gain + noise * noise)
                    count += 1
        chi2[s] = total / max(count - 5, 1)
        converged[s] = (math.isfinite(x[s]) and math.isfinite(y[s]) and col0[s] + 0.5 < x[s] < col0[s] + size - 1.5
                        and row0[s] + 0.5 < y[s] < row0[s] + size - 1.5 and sigma_var[s] > 0.0)
    return x, y, flux, sigma, sigma_var, chi2, converged, offset


def warm_up() -> None:
    """Compile (or load from the cache) the fit for the float64 windows estimate passes."""
    data = np.zeros((1, 7, 7))
    data[0, 3, 3] = 100.0
    fit_psf_width(data, np.ones((1, 7, 7), np.bool_), np.zeros(1), np.zeros(1), np.full(1, 3.0), np.full(1, 3.0),
                  np.full(1, 100.0), np.full(1, 1.0), 1.0, 1.0, 5)
