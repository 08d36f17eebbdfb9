# SPDX-License-Identifier: Apache-2.0
"""
Weighted least-squares fit of pixel-integrated Gaussian PSFs to small image windows.

One or several sources per window (several = a blend fitted jointly), all windows at once.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import erf

_ROOT2 = np.sqrt(2.0)
USE_COMPILED = True  # fits through kernels.fit_single_psf and blend_fit_kernel.fit_multi_psf (False: numpy)
_INV_ROOT_2PI = 1.0 / np.sqrt(2.0 * np.pi)


def pixel_integrated_profile(edges_lo: np.ndarray, centre: np.ndarray, sigma: float):
    """
    Return the fraction of a 1-D Gaussian (centre [px], sigma [px]) in pixels [lo, lo + 1), and its derivative.

    The derivative is with respect to the centre [1/px]. Broadcasts edges_lo against centre.
    """
    a = (edges_lo - centre) / sigma
    b = a + 1.0 / sigma
    prob = 0.5 * (erf(b / _ROOT2) - erf(a / _ROOT2))
    deriv = (np.exp(-0.5 * a * a) - np.exp(-0.5 * b * b)) * (_INV_ROOT_2PI / sigma)
    return prob, deriv


def _inverse_3x3(a: np.ndarray) -> np.ndarray:
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


def gather_windows(image: np.ndarray, col0: np.ndarray, row0: np.ndarray, size: int | tuple[int, int]):
    """
    Return (n, rows, cols) float windows with top-left pixel (col0, row0) [px], and a mask.

    size: an int for square windows or (rows, cols); the mask holds the pixels inside the
    image (outside ones read as 0).
    """
    height, width = image.shape
    size_r, size_c = (size, size) if np.isscalar(size) else size
    rows = np.asarray(row0, np.int64)[:, None] + np.arange(size_r)[None, :]
    cols = np.asarray(col0, np.int64)[:, None] + np.arange(size_c)[None, :]
    inside = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    data = image[np.clip(rows, 0, height - 1)[:, :, None], np.clip(cols, 0, width - 1)[:, None, :]]
    return np.where(inside, data.astype(np.float64), 0.0), inside


class PsfWindows(NamedTuple):
    """
    n windows of background-subtracted data (n, S, S) [ADU].

    Valid (n, S, S) bool, the usable pixels; col0, row0 (n,) the top-left pixel [px].
    """

    data: np.ndarray
    valid: np.ndarray
    col0: np.ndarray
    row0: np.ndarray


class PsfStart(NamedTuple):
    """Starting values of M sources per window, (n, M) each (or (n,) for M = 1): x, y [px], flux [ADU]."""

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray


class PsfSettings(NamedTuple):
    """
    The fit's fixed values.

    Sigma, the PSF 1-sigma [px]; noise, the 1-sigma pixel noise [ADU]; gain [e-/ADU];
    iterations, the most Gauss-Newton steps; halo_sigmas [px], halo_shares (k,) float64:
    wider Gaussians on the same centre with these shares of the flux, the core (sigma) the
    rest (core_halo_psf; none: one Gaussian).
    """

    sigma: float
    noise: float
    gain: float
    iterations: int
    halo_sigmas: np.ndarray = np.zeros(0)
    halo_shares: np.ndarray = np.zeros(0)


class PsfFit(NamedTuple):
    """
    Fitted sources (n, M).

    X, y [px], flux [ADU], cov (n, M, 2, 2) [px^2], converged (bool), flux_var [ADU^2] (the
    flux's variance: its SNR is flux / sqrt(flux_var)).
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    cov: np.ndarray
    converged: np.ndarray
    flux_var: np.ndarray


def fit_psf_windows(windows: PsfWindows, start: PsfStart, sigma: float, noise: float, gain: float,
                    iterations: int = 10) -> PsfFit:
    """
    Fit M Gaussian PSFs (fixed sigma [px]) per window to the n `windows`, starting at `start`.

    The windows hold background-subtracted data [ADU] (their `valid` pixels).

    Model: mu_ij = sum_m F_m P(col_j; x_m) P(row_i; y_m), P = PSF integral over the pixel;
    weights 1 / (mu / gain + noise^2) (gain e-/ADU, noise 1-sigma ADU). Gauss-Newton on
    (x_m, y_m, F_m) with a 1 px trust region and a whisper of Levenberg-Marquardt damping, so
    one degenerate window cannot fail the batch. The covariance of (x_m, y_m) is the inverse
    Fisher information at the solution (the Cramer-Rao bound).
    """
    x0, y0, flux0 = (np.atleast_2d(np.asarray(v, float)) for v in start)
    if x0.shape[0] != windows.data.shape[0]:
        x0, y0, flux0 = x0.T, y0.T, flux0.T
    n, m = x0.shape
    if n == 0:
        return PsfFit(x0, y0, flux0, np.zeros((0, m, 2, 2)), np.zeros((0, m), bool), np.zeros((0, m)))
    settings = PsfSettings(float(sigma), float(noise), float(gain), int(iterations))
    if m == 1 and USE_COMPILED:  # the common case, compiled: numpy's per-call overhead dominates it
        from .kernels import fit_single_psf

        compiled = PsfWindows(np.ascontiguousarray(windows.data, np.float64),
                              np.ascontiguousarray(windows.valid, np.bool_),
                              np.asarray(windows.col0, np.float64), np.asarray(windows.row0, np.float64))
        x, y, flux, cov, flux_var, ok = fit_single_psf(compiled, PsfStart(x0[:, 0].copy(), y0[:, 0].copy(),
                                                                          flux0[:, 0].copy()), settings)
        return PsfFit(x[:, None], y[:, None], flux[:, None], cov[:, None], ok[:, None], flux_var[:, None])
    if USE_COMPILED:  # blends: one window per call, so numpy's per-call overhead would dominate
        from .blend_fit_kernel import fit_multi_psf

        x, y, flux, cov, flux_var, ok = fit_multi_psf(
            np.ascontiguousarray(windows.data, np.float64), np.ascontiguousarray(windows.valid, np.bool_),
            np.ascontiguousarray(windows.col0, np.float64), np.ascontiguousarray(windows.row0, np.float64),
            np.ascontiguousarray(x0), np.ascontiguousarray(y0), np.ascontiguousarray(flux0),
            settings.sigma, settings.noise, settings.gain, settings.iterations)
        return PsfFit(x, y, flux, cov, ok, flux_var)
    return _fit_psf_numpy(windows, PsfStart(x0, y0, flux0), sigma, noise, gain, iterations)


def _fit_psf_numpy(windows: PsfWindows, start: PsfStart, sigma, noise, gain, iterations) -> PsfFit:
    """fit_psf_windows in numpy, any M; start (n, M)."""
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
        return _inverse_3x3(matrix) if m == 1 else np.linalg.inv(matrix)

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


def fit_gaussian_psf(residual: np.ndarray, x0: np.ndarray, y0: np.ndarray, flux0: np.ndarray, sigma: float,
                     noise: float, gain: float, half: int = 4, iterations: int = 10):
    """
    Fit one PSF per spot on (2 half + 1)^2 windows of a background-subtracted image [ADU].

    The windows are centred on the rounded initial positions. Returns x, y, flux (N,), cov (N, 2,
    2), converged.
    """
    x0, y0 = np.asarray(x0, float), np.asarray(y0, float)
    col0, row0 = np.rint(x0).astype(np.int64) - half, np.rint(y0).astype(np.int64) - half
    data, valid = gather_windows(residual, col0, row0, 2 * half + 1)
    fit = fit_psf_windows(PsfWindows(data, valid, col0, row0),
                          PsfStart(x0[:, None], y0[:, None], np.asarray(flux0, float)[:, None]), sigma, noise, gain,
                          iterations)
    return fit.x[:, 0], fit.y[:, 0], fit.flux[:, 0], fit.cov[:, 0], fit.converged[:, 0]
