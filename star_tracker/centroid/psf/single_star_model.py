# SPDX-License-Identifier: Apache-2.0
"""
The PSF model of a frame's single stars: the round Gaussian, the estimate's elliptical one, or a core and halo.

The frame's bright stars judge (median reduced chi^2 of those of flux SNR >= BRIGHT_SNR):
- an astigmatic frame (FitContext.elliptical: the estimate elongated beyond 1.2:1, no known
  rate) is refitted with its elliptical Gaussian, kept unless its bright stars fit it no
  better than the round one (real DSLR frames whose moments read 1.23:1 fitted it worse:
  chi^2 2.56 vs 2.44, residuals against the catalogue 2-28 % larger); with fewer than
  MIN_JUDGED bright stars (faint frames) the estimate's shape is kept;
- a round-model frame with WINGS_MIN_STARS or more bright round stars whose chi^2 exceeds
  WINGS_MIN_CHI2 is refitted with the core/halo shape fitted to them (psf.core_halo)
  when that lowers the chi^2 below WINGS_GAIN x the Gaussian's (judged on 6 stars, a real
  frame's shape lowered their chi^2 1.58 -> 1.06 and raised the residuals of its 100
  matched stars against the catalogue by 9 %).
Never in a frame of ring stars (their own profile, psf.empirical) or where a known rate
smears the stars (FitContext.own_psf False).
"""
from __future__ import annotations

import numpy as np

from .core_halo import SHAPE_STARS, CoreHaloPsf, estimate_core_halo
from .elliptical import fit_elliptical
from ..windows import PsfStart, PsfWindows
from .gaussian_fit import PsfFit
from ..records import FitContext

BRIGHT_SNR = 30.0  # stars whose chi^2 judges the model (fainter ones' residuals are noise whatever the PSF)
MIN_JUDGED = 5  # fewer bright stars than this judge nothing: the default stays
WINGS_MIN_STARS = 15  # a core/halo shape (5 values) is judged on at least this many bright round stars
WINGS_MIN_CHI2 = 1.5  # bright round stars' median reduced chi^2 under the Gaussian above this: look for wings
WINGS_GAIN = 0.7  # ... and use the core/halo shape when it brings that median below this x the Gaussian's


def fit_frame_model(context: FitContext, windows: PsfWindows, fit: PsfFit, start: PsfStart, round_: np.ndarray):
    """
    Return (model, fits) of the single-star `windows` (see the module docstring).

    `fit`: their round-Gaussian fits (one source each); `start`: its starting values;
    `round_`: (n,) the spots not elongated. model None: the round Gaussian, whose fits are
    returned as they are.
    """
    if not context.own_psf or context.rings:
        return None, fit
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = fit.flux[:, 0] / np.sqrt(np.abs(fit.flux_var[:, 0]))
    bright = fit.converged[:, 0] & (snr >= BRIGHT_SNR)
    gaussian = CoreHaloPsf(context.sigma)
    if context.elliptical is not None:
        refit = _refit(context, context.elliptical, windows, fit, start)
        judged = np.flatnonzero(bright & refit.converged[:, 0])
        if judged.size < MIN_JUDGED or (_median_chi2(context.elliptical, windows, refit, judged, context)
                                        < _median_chi2(gaussian, windows, fit, judged, context)):
            return context.elliptical, refit
    judged = np.flatnonzero(bright & round_)
    if judged.size < WINGS_MIN_STARS:
        return None, fit
    one = _median_chi2(gaussian, windows, fit, judged, context)
    if not one > WINGS_MIN_CHI2:
        return None, fit
    pick = judged[np.argsort(-snr[judged])[:SHAPE_STARS]]
    psf = estimate_core_halo(_take(windows, pick), fit.x[pick, 0], fit.y[pick, 0], context.sigma, context.noise,
                             context.gain)
    if psf is None:
        return None, fit
    refit = _refit(context, psf, windows, fit, start)
    ok = judged[refit.converged[judged, 0]]
    if ok.size < WINGS_MIN_STARS or not _median_chi2(psf, windows, refit, ok, context) < WINGS_GAIN * one:
        return None, fit
    return psf, refit


def _refit(context: FitContext, psf, windows: PsfWindows, fit: PsfFit, start: PsfStart) -> PsfFit:
    """Fit `psf` to the windows from the round Gaussian's position and flux where it converged, else from `start`."""
    converged = fit.converged[:, 0]
    x0 = np.where(converged, fit.x[:, 0], start.x[:, 0])
    y0 = np.where(converged, fit.y[:, 0], start.y[:, 0])
    flux0 = np.where(converged, fit.flux[:, 0], np.maximum(start.flux[:, 0], 1.0))
    if isinstance(psf, CoreHaloPsf):
        return psf.fit(windows, PsfStart(x0, y0, flux0), context.noise, context.gain)
    x, y, flux, cov, flux_var, ok = fit_elliptical(psf, windows, PsfStart(x0, y0, flux0), context.noise, context.gain)
    return PsfFit(x[:, None], y[:, None], flux[:, None], cov[:, None], ok[:, None], flux_var[:, None])


def window_shares(psf, col0, row0, x, y, size: int, sigma: float) -> np.ndarray:
    """
    Return the (n, size, size) shares of unit-flux stars at (x, y) [px] in windows with top-left pixel (col0, row0).

    psf: None for the round Gaussian of 1-sigma `sigma` [px], else any model with `sample`
    (CoreHaloPsf through its separable profiles).
    """
    if psf is None:
        psf = CoreHaloPsf(sigma)
    if isinstance(psf, CoreHaloPsf):
        return psf.window_shares(col0, row0, x, y, size)
    steps = np.arange(size, dtype=float)
    dx = (np.asarray(col0, float)[:, None] + steps)[:, None, :] - np.asarray(x, float)[:, None, None]
    dy = (np.asarray(row0, float)[:, None] + steps)[:, :, None] - np.asarray(y, float)[:, None, None]
    share, _, _ = psf.sample(*np.broadcast_arrays(dx, dy))
    return share


def _median_chi2(psf, windows: PsfWindows, fit: PsfFit, rows: np.ndarray, context: FitContext) -> float:
    """Return the median reduced chi^2 of fits `rows` under `psf` (any model with `sample`)."""
    data, valid = windows.data[rows], windows.valid[rows]
    share = window_shares(psf, np.asarray(windows.col0)[rows], np.asarray(windows.row0)[rows], fit.x[rows, 0],
                          fit.y[rows, 0], data.shape[1], context.sigma)
    model = fit.flux[rows, 0][:, None, None] * share
    residual = np.where(valid, data - model, 0.0)
    chi2 = np.sum(residual ** 2 / (np.maximum(model, 0.0) / context.gain + context.noise ** 2), axis=(1, 2))
    return float(np.median(chi2 / np.maximum(valid.sum(axis=(1, 2)) - 3, 1)))


def _take(windows: PsfWindows, rows) -> PsfWindows:
    return PsfWindows(*(np.asarray(a)[rows] for a in windows))
