# SPDX-License-Identifier: Apache-2.0
"""
One pixel-integrated Gaussian PSF per window, fitted by weighted Gauss-Newton, compiled (numba).

The single stars' fit of gaussian_fit.fit_psf_windows (M = 1), and with halo Gaussians on the
same centre the core/halo model's (core_halo.CoreHaloPsf): per star the work is too small
for numpy's per-call overhead to pay off.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ..windows import PsfStart, PsfWindows
from .matrix_kernel import invert_3x3
from .profile_kernel import gaussian_profile


class PsfSettings(NamedTuple):
    """
    The fit's fixed values.

    Sigma, the PSF 1-sigma [px]; noise, the 1-sigma pixel noise [ADU]; gain [e-/ADU];
    iterations, the most Gauss-Newton steps; halo_sigmas [px], halo_shares (k,) float64:
    wider Gaussians on the same centre with these shares of the flux, the core (sigma) the
    rest (core_halo; none: one Gaussian).
    """

    sigma: float
    noise: float
    gain: float
    iterations: int
    halo_sigmas: np.ndarray = np.zeros(0)
    halo_shares: np.ndarray = np.zeros(0)


@njit(cache=True, fastmath=False)
def fit_single_psf(windows, start, settings):
    """
    One pixel-integrated Gaussian PSF per window.

    The same weighted Gauss-Newton as gaussian_fit.fit_psf_windows with M = 1 (1 px trust region,
    1e-9 relative damping, stop when the position step is below 1 % of its sigma, covariance
    from the last step's inverse). windows: windows.PsfWindows, data float64 and valid bool
    (n, S, S), col0, row0 float64 (n,); start: windows.PsfStart of (n,) arrays; settings:
    PsfSettings (halo components: the core and halo Gaussians of core_halo).
    Returns x, y, flux (n,), cov (n, 2, 2), flux_var (n,), converged (n,).
    """
    data, valid, col0, row0 = windows.data, windows.valid, windows.col0, windows.row0
    x0, y0, flux0 = start.x, start.y, start.flux
    sigma, noise, gain, iterations = settings.sigma, settings.noise, settings.gain, settings.iterations
    halo_sigmas, halo_shares = settings.halo_sigmas, settings.halo_shares
    halos = halo_sigmas.size
    core_share = 1.0 - halo_shares.sum()
    n, size, _ = data.shape
    x, y, flux = x0.copy(), y0.copy(), np.maximum(flux0.copy(), 1e-9)
    cov = np.full((n, 2, 2), np.nan)
    flux_var = np.full(n, np.nan)
    converged = np.zeros(n, np.bool_)
    px = np.empty(size)
    dpx = np.empty(size)
    py = np.empty(size)
    dpy = np.empty(size)
    hx, dhx = np.empty((halos, size)), np.empty((halos, size))  # the halo Gaussians' profiles
    hy, dhy = np.empty((halos, size)), np.empty((halos, size))
    normal = np.empty((3, 3))
    inv = np.empty((3, 3))
    grad = np.empty(3)
    jac = np.empty(3)
    for s in range(n):
        for _ in range(iterations):
            gaussian_profile(col0[s] - 0.5, x[s], sigma, size, px, dpx)
            gaussian_profile(row0[s] - 0.5, y[s], sigma, size, py, dpy)
            for h in range(halos):
                gaussian_profile(col0[s] - 0.5, x[s], halo_sigmas[h], size, hx[h], dhx[h])
                gaussian_profile(row0[s] - 0.5, y[s], halo_sigmas[h], size, hy[h], dhy[h])
            normal[:, :] = 0.0
            grad[:] = 0.0
            f = flux[s]
            for i in range(size):
                for j in range(size):
                    if not valid[s, i, j]:
                        continue
                    if halos:
                        shape = core_share * py[i] * px[j]
                        slope_x = core_share * py[i] * dpx[j]
                        slope_y = core_share * dpy[i] * px[j]
                        for h in range(halos):
                            shape += halo_shares[h] * hy[h, i] * hx[h, j]
                            slope_x += halo_shares[h] * hy[h, i] * dhx[h, j]
                            slope_y += halo_shares[h] * dhy[h, i] * hx[h, j]
                        jac[0] = f * slope_x
                        jac[1] = f * slope_y
                    else:
                        shape = py[i] * px[j]
                        jac[0] = f * py[i] * dpx[j]
                        jac[1] = f * dpy[i] * px[j]
                    model = f * shape
                    weight = 1.0 / (max(model, 0.0) / gain + noise * noise)
                    jac[2] = shape
                    resid = data[s, i, j] - model
                    for a in range(3):
                        wa = weight * jac[a]
                        grad[a] += wa * resid
                        for b in range(a, 3):
                            normal[a, b] += wa * jac[b]
            for a in range(3):
                for b in range(a):
                    normal[a, b] = normal[b, a]
                normal[a, a] += 1e-9 * abs(normal[a, a]) + 1e-300
            if not invert_3x3(normal, inv):
                break
            step_x = inv[0, 0] * grad[0] + inv[0, 1] * grad[1] + inv[0, 2] * grad[2]
            step_y = inv[1, 0] * grad[0] + inv[1, 1] * grad[1] + inv[1, 2] * grad[2]
            step_f = inv[2, 0] * grad[0] + inv[2, 1] * grad[1] + inv[2, 2] * grad[2]
            step_x = min(max(step_x, -1.0), 1.0)
            step_y = min(max(step_y, -1.0), 1.0)
            x[s] += step_x
            y[s] += step_y
            flux[s] = max(flux[s] + step_f, 1e-9)
            cov[s, 0, 0], cov[s, 0, 1], cov[s, 1, 0], cov[s, 1, 1] = inv[0, 0], inv[0, 1], inv[1, 0], inv[1, 1]
            flux_var[s] = inv[2, 2]
            if (step_x * step_x <= max(1e-4 * abs(inv[0, 0]), 1e-10)
                    and step_y * step_y <= max(1e-4 * abs(inv[1, 1]), 1e-10)):
                break
        converged[s] = (math.isfinite(cov[s, 0, 0]) and math.isfinite(cov[s, 1, 1]) and math.isfinite(cov[s, 0, 1])
                        and cov[s, 0, 0] > 0 and cov[s, 1, 1] > 0 and math.isfinite(x[s]) and math.isfinite(y[s])
                        and col0[s] + 0.5 < x[s] < col0[s] + size - 1.5 and row0[s] + 0.5 < y[s] < row0[s] + size - 1.5)
    return x, y, flux, cov, flux_var, converged


def warm_up() -> None:
    """Compile (or load from the cache) the fit for the float64 windows gaussian_fit passes, with and without halos."""
    data = np.zeros((1, 7, 7))
    data[0, 3, 3] = 100.0
    fit_single_psf(PsfWindows(data, np.ones((1, 7, 7), np.bool_), np.zeros(1), np.zeros(1)),
                   PsfStart(np.full(1, 3.0), np.full(1, 3.0), np.full(1, 100.0)),
                   PsfSettings(1.0, 1.0, 1.0, 5))
