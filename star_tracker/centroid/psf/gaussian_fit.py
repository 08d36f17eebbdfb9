# SPDX-License-Identifier: Apache-2.0
"""
Weighted least-squares fit of pixel-integrated Gaussian PSFs to small image windows.

One or several sources per window (several = a blend fitted jointly), all windows at once.
The fits are compiled beside this module: gaussian_fit_kernel (one source per window) and
blend_fit_kernel (several); pixel_integrated_profile is the model's 1-D profile in numpy.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import erf

from ..windows import PsfStart, PsfWindows, gather_windows
from .blend_fit_kernel import fit_multi_psf
from .gaussian_fit_kernel import PsfSettings, fit_single_psf

_ROOT2 = np.sqrt(2.0)
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
    if m == 1:  # the common case
        compiled = PsfWindows(np.ascontiguousarray(windows.data, np.float64),
                              np.ascontiguousarray(windows.valid, np.bool_),
                              np.asarray(windows.col0, np.float64), np.asarray(windows.row0, np.float64))
        x, y, flux, cov, flux_var, ok = fit_single_psf(compiled, PsfStart(x0[:, 0].copy(), y0[:, 0].copy(),
                                                                          flux0[:, 0].copy()), settings)
        return PsfFit(x[:, None], y[:, None], flux[:, None], cov[:, None], ok[:, None], flux_var[:, None])
    # Blends: one window per call.
    x, y, flux, cov, flux_var, ok = fit_multi_psf(
        np.ascontiguousarray(windows.data, np.float64), np.ascontiguousarray(windows.valid, np.bool_),
        np.ascontiguousarray(windows.col0, np.float64), np.ascontiguousarray(windows.row0, np.float64),
        np.ascontiguousarray(x0), np.ascontiguousarray(y0), np.ascontiguousarray(flux0),
        settings.sigma, settings.noise, settings.gain, settings.iterations)
    return PsfFit(x, y, flux, cov, ok, flux_var)


def fit_gaussian_psf(residual: np.ndarray, start: PsfStart, sigma: float, noise: float, gain: float, half: int = 4,
                     iterations: int = 10):
    """
    Fit one PSF per spot on (2 half + 1)^2 windows of a background-subtracted image [ADU].

    start: x, y [px] and flux [ADU] (N,) to start from; the windows are centred on the rounded
    initial positions. sigma: the PSF 1-sigma [px]; noise: the pixel noise [ADU]; gain
    [e-/ADU]. Returns x, y, flux (N,), cov (N, 2, 2), converged.
    """
    x0, y0, flux0 = np.asarray(start.x, float), np.asarray(start.y, float), start.flux
    col0, row0 = np.rint(x0).astype(np.int64) - half, np.rint(y0).astype(np.int64) - half
    data, valid = gather_windows(residual, col0, row0, 2 * half + 1)
    fit = fit_psf_windows(PsfWindows(data, valid, col0, row0),
                          PsfStart(x0[:, None], y0[:, None], np.asarray(flux0, float)[:, None]), sigma, noise, gain,
                          iterations)
    return fit.x[:, 0], fit.y[:, 0], fit.flux[:, 0], fit.cov[:, 0], fit.converged[:, 0]
