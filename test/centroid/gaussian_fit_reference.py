# SPDX-License-Identifier: Apache-2.0
"""
The Gaussian PSF fit in numpy: the tests' reference for the compiled fits (gaussian_fit_kernel, blend_fit_kernel).

The same weighted Gauss-Newton as star_tracker.centroid.psf.gaussian_fit.fit_psf_windows
(1 px trust region, 1e-9 relative damping, stop when every position step is below 1 % of
its sigma, covariance from the last step's inverse), written independently of the kernels
with numpy's batched linear algebra. `use_numpy_fits` makes fit_psf_windows run it.
"""
from __future__ import annotations

import numpy as np

from star_tracker.centroid.psf import gaussian_fit
from star_tracker.centroid.psf.gaussian_fit import PsfFit, pixel_integrated_profile
from star_tracker.centroid.windows import PsfStart, PsfWindows


def inverse_3x3(a: np.ndarray) -> np.ndarray:
    """Inverses of a stack of 3x3 matrices (k, 3, 3) by cofactors (inf/nan when singular)."""
    c00 = a[:, 1, 1] * a[:, 2, 2] - a[:, 1, 2] * a[:, 2, 1]
    c01 = a[:, 1, 2] * a[:, 2, 0] - a[:, 1, 0] * a[:, 2, 2]
    c02 = a[:, 1, 0] * a[:, 2, 1] - a[:, 1, 1] * a[:, 2, 0]
    out = np.empty_like(a)
    out[:, 0, 0], out[:, 1, 0], out[:, 2, 0] = c00, c01, c02
    out[:, 0, 1] = a[:, 0, 2] * a[:, 2, 1] - a[:, 0, 1] * a[:, 2, 2]
    out[:, 0, 2] = a[:, 0, 1] * a[:, 1, 2] - a[:, 0, 2] * a[:, 1, 1]
    out[:, 1, 1] = a[:, 0, 0] * a[:, 2, 2] - a[:, 0, 2] * a[:, 2, 0]
    out[:, 1, 2] = a[:, 0, 2] * a[:, 1, 0] - a[:, 0, 0] * a[:, 1, 2]
    out[:, 2, 1] = a[:, 0, 1] * a[:, 2, 0] - a[:, 0, 0] * a[:, 2, 1]
    out[:, 2, 2] = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
    det = a[:, 0, 0] * c00 + a[:, 0, 1] * c01 + a[:, 0, 2] * c02
    with np.errstate(divide="ignore", invalid="ignore"):
        return out / det[:, None, None]


def fit_psf_numpy(windows: PsfWindows, start: PsfStart, sigma, noise, gain, iterations) -> PsfFit:
    """gaussian_fit.fit_psf_windows in numpy, any M; start (n, M)."""
    data, valid, col0, row0 = windows
    x0, y0, flux0 = start
    n, m = x0.shape
    size = data.shape[1]
    edges_c = (np.asarray(col0, float)[:, None] + np.arange(size) - 0.5)[:, None, :]  # (n, 1, S)
    edges_r = (np.asarray(row0, float)[:, None] + np.arange(size) - 0.5)[:, None, :]
    x, y, flux = x0.copy(), y0.copy(), np.maximum(flux0.copy(), 1e-9)
    target = np.where(valid, data, 0.0).reshape(n, -1)
    mask = valid.reshape(n, -1)
    eye = np.eye(3 * m)[None]

    def normal_equations(a):
        """Return the normal matrix and gradient of windows `a` at the current parameters."""
        k = a.size
        px, dpx = pixel_integrated_profile(edges_c[a], x[a][:, :, None], sigma)  # (k, M, S)
        py, dpy = pixel_integrated_profile(edges_r[a], y[a][:, :, None], sigma)
        f = flux[a][:, :, None, None]
        shape = py[:, :, :, None] * px[:, :, None, :]  # (k, M, S, S)
        model = (f * shape).sum(axis=1).reshape(k, -1)
        weight = np.where(mask[a], 1.0 / (np.maximum(model, 0.0) / gain + noise * noise), 0.0)
        jac = np.stack([f * py[:, :, :, None] * dpx[:, :, None, :], f * dpy[:, :, :, None] * px[:, :, None, :],
                        shape], axis=2).reshape(k, 3 * m, -1)  # (k, 3M, P): rows x_m, y_m, F_m
        jw = jac * weight[:, None, :]
        normal = jw @ jac.transpose(0, 2, 1)
        gradient = (jw @ (target[a] - model)[:, :, None])[..., 0]
        return normal, gradient

    def inverse(matrix):  # closed form for the common 3x3 case: LAPACK's batched call costs more
        return inverse_3x3(matrix) if m == 1 else np.linalg.inv(matrix)

    def damped(normal):  # a whisper of Levenberg-Marquardt damping keeps every system solvable
        return normal + (1e-9 * np.abs(np.diagonal(normal, axis1=1, axis2=2)) + 1e-300)[:, :, None] * eye

    # Gauss-Newton on the windows not yet converged (most need two steps from a centre of gravity).
    active = np.arange(n)
    full = np.full((n, 3 * m, 3 * m), np.nan)
    for _ in range(iterations):
        normal, gradient = normal_equations(active)
        inv = inverse(damped(normal))
        # The covariance is the inverse information of the last step: once converged the step
        # is below 1 % of a sigma, so it is the information at the solution.
        full[active] = inv
        step = (inv @ gradient[..., None])[..., 0].reshape(active.size, m, 3)
        step[:, :, :2] = np.clip(step[:, :, :2], -1.0, 1.0)  # trust region: 1 px per step
        x[active] += step[:, :, 0]
        y[active] += step[:, :, 1]
        flux[active] = np.maximum(flux[active] + step[:, :, 2], 1e-9)
        # Converged: the position step is a negligible fraction of the position's own sigma.
        var = np.abs(np.diagonal(inv, axis1=1, axis2=2)).reshape(active.size, m, 3)
        moving = np.any(step[:, :, :2] ** 2 > np.maximum(1e-4 * var[:, :, :2], 1e-10), axis=(1, 2))
        active = active[moving]
        if active.size == 0:
            break
    cov = np.empty((n, m, 2, 2))
    flux_var = np.empty((n, m))
    for k in range(m):
        cov[:, k] = full[:, 3 * k:3 * k + 2, 3 * k:3 * k + 2]
        flux_var[:, k] = full[:, 3 * k + 2, 3 * k + 2]
    lo_c, lo_r = np.asarray(col0, float)[:, None], np.asarray(row0, float)[:, None]
    converged = (np.all(np.isfinite(cov.reshape(n, m, -1)), axis=2) & (cov[:, :, 0, 0] > 0) & (cov[:, :, 1, 1] > 0)
                 & np.isfinite(x) & np.isfinite(y) & (x > lo_c + 0.5) & (x < lo_c + size - 1.5)
                 & (y > lo_r + 0.5) & (y < lo_r + size - 1.5))
    return PsfFit(x, y, flux, cov, converged, flux_var)


def use_numpy_fits(monkeypatch) -> None:
    """Make gaussian_fit.fit_psf_windows fit with fit_psf_numpy, not its compiled kernels (single stars, blends)."""
    def single(windows, start, settings):
        fit = fit_psf_numpy(windows, PsfStart(start.x[:, None], start.y[:, None], start.flux[:, None]),
                            settings.sigma, settings.noise, settings.gain, settings.iterations)
        return fit.x[:, 0], fit.y[:, 0], fit.flux[:, 0], fit.cov[:, 0], fit.flux_var[:, 0], fit.converged[:, 0]

    def multi(data, valid, col0, row0, x0, y0, flux0, sigma, noise, gain, iterations):
        fit = fit_psf_numpy(PsfWindows(data, valid, col0, row0), PsfStart(x0, y0, flux0), sigma, noise, gain,
                            iterations)
        return fit.x, fit.y, fit.flux, fit.cov, fit.flux_var, fit.converged

    monkeypatch.setattr(gaussian_fit, "fit_single_psf", single)
    monkeypatch.setattr(gaussian_fit, "fit_multi_psf", multi)
