# SPDX-License-Identifier: Apache-2.0
"""
The streak fits' common ground.

Their result record (StreakFit), input checks, window bounds and batches, and how a batch's
solution is stored.

Fitting: weighted least squares by Levenberg-Marquardt, each spot in its own window (padded
to one size per batch, pixels outside the window, off the image or non-finite masked), all
spots of a batch at once (levenberg_marquardt) or, for the free fit, one at a time compiled
(streak.free_fit_kernel); one spot's failure never affects another's. Noise model as fit_gaussian_psf: pixel
variance = max(model, 0) / gain + noise^2 [ADU^2]; residual images are background-
subtracted [ADU]. The covariance reported is the (x, y) block of the inverse Fisher matrix
of all fitted parameters at the solution.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .model import StreakWindows

PSF_RADIUS_SIGMA = 4.0  # window margin beyond the streak ends [sigma] (plus 1 px)
# A converged fit's flux exceeds this many sigma: five free parameters find some streak in pure
# noise, with flux > 2 sigma in ~20 % of empty windows and > 3 sigma in ~3 %.
SIGNIFICANT_FLUX = 3.0
_MAX_WINDOW_ELEMENTS = 3_000_000  # spots x parameters x pixels per batch (memory bound)
_MAX_PADDING = 2.0  # padded window pixels per own window pixel in a batch
# ... once the batch holds this many padded pixels: below it a batch of the numpy solver
# (levenberg_marquardt) costs its fixed per-iteration overhead (~0.2 ms x 30 steps), not its
# pixels (the compiled free fit works on each spot's own window: padding costs it memory only).
_PADDING_FREE_PIXELS = 20_000


class StreakImage(NamedTuple):
    """
    The image a streak fit reads, and its noise.

    residual (H, W) image minus background [ADU]; sigma the PSF 1-sigma [px]; noise the
    1-sigma pixel noise [ADU]; gain [e-/ADU]; excluded (H, W) bool pixels no fit may use
    (clipped at the full well: they carry no shape information), or None.
    """

    residual: np.ndarray
    sigma: float
    noise: float
    gain: float
    excluded: np.ndarray | None = None


class StreakFitSetup(NamedTuple):
    """
    What every batch of a streak fit reads.

    Residual (H, W) image minus background [ADU]; excluded (H, W) bool pixels no fit may use,
    or None; sigma the PSF 1-sigma [px]; noise the 1-sigma pixel noise [ADU]; gain [e-/ADU];
    iterations, the most Levenberg-Marquardt steps.
    """

    residual: np.ndarray
    excluded: np.ndarray | None
    sigma: float
    noise: float
    gain: float
    iterations: int


@dataclass(frozen=True)
class StreakFit:
    """
    Fitted streaks, parallel arrays of N entries.

    x, y: position at mid-exposure [px]; flux: total [ADU]; length: streak length [px] (end to
    end of the exposure); angle: streak direction from +x toward +y [rad], in (-pi/2, pi/2]
    from a free fit (the sense of motion is unknown; NaN when the length is not significant:
    < 2 length_sigma), in (-pi, pi] from start to end for a fit on a known path (NaN if the
    path has no extent); cov: (N, 2, 2) covariance of (x, y) [px^2], the (x, y) block of the
    inverse Fisher matrix of all fitted parameters at the solution; length_sigma: 1-sigma of
    length [px] (0 when the path was given); converged: the fit reached a minimum with a
    flux above SIGNIFICANT_FLUX sigma, a finite covariance and its centre inside its window,
    on a window free of non-finite pixels (the values are filled in either way when a fit
    was possible, NaN otherwise). flux_sigma [ADU], angle_sigma [rad] (0 on a given path):
    1-sigma errors. chi2: weighted sum of squared residuals over the window at the solution
    (weights of the noise model); dof: the window's used pixels minus the fitted parameters.
    chi2 well above dof (by many sqrt(2 dof)) means light the model does not describe: a
    neighbour's star or streak merged into the spot.
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    length: np.ndarray
    angle: np.ndarray
    cov: np.ndarray
    length_sigma: np.ndarray
    converged: np.ndarray
    flux_sigma: np.ndarray
    angle_sigma: np.ndarray
    chi2: np.ndarray | None = None
    dof: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("chi2", "dof"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(self.x.size, np.nan))

    def __len__(self) -> int:
        return int(self.x.size)

    @staticmethod
    def failed(n: int) -> "StreakFit":
        """Return n unconverged fits, every value NaN."""
        nan = np.full(n, np.nan)
        return StreakFit(nan.copy(), nan.copy(), nan.copy(), nan.copy(), nan.copy(), np.full((n, 2, 2), np.nan),
                         nan.copy(), np.zeros(n, bool), nan.copy(), nan.copy())


def check_common_inputs(residual, sigma, noise, gain, iterations, *per_spot):
    residual = np.asarray(residual)
    if residual.ndim != 2 or residual.size == 0 or residual.dtype.kind not in "uif":
        raise ValueError(f"residual must be a non-empty 2-D numeric image [ADU], got shape {residual.shape} "
                         f"dtype {residual.dtype}")
    for name, value in (("sigma", sigma), ("noise", noise), ("gain", gain)):
        if not (np.isscalar(value) and np.isreal(value) and np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    if not (isinstance(iterations, (int, np.integer)) and iterations >= 0):
        raise ValueError(f"iterations must be an integer >= 0, got {iterations!r}")
    try:
        arrays = [np.asarray(a, dtype=float).ravel() for a in per_spot]
    except (TypeError, ValueError):
        raise ValueError("per-spot inputs must be numeric arrays") from None
    if len({a.size for a in arrays}) > 1:
        raise ValueError(f"per-spot inputs must have one length, got sizes {[a.size for a in arrays]}")
    return residual, arrays


def check_excluded(excluded, residual: np.ndarray):
    """`excluded` as a (H, W) bool image matching `residual`, or None."""
    if excluded is None:
        return None
    excluded = np.asarray(excluded, dtype=bool)
    if excluded.shape != residual.shape:
        raise ValueError(f"excluded must have the residual's shape {residual.shape}, got {excluded.shape}")
    return excluded


def window_bounds(residual, valid, lo_x, hi_x, lo_y, hi_y):
    """
    Integer pixel bounds of each spot's window (inclusive, clipped to the image) from float extents [px].

    Spots whose window misses the image become invalid.
    """
    height, width = residual.shape
    col_lo, col_hi = (np.floor(np.where(valid, lo_x, 0.0)).astype(np.int64),
                      np.ceil(np.where(valid, hi_x, 0.0)).astype(np.int64))
    row_lo, row_hi = (np.floor(np.where(valid, lo_y, 0.0)).astype(np.int64),
                      np.ceil(np.where(valid, hi_y, 0.0)).astype(np.int64))
    valid = valid & (col_hi >= 0) & (col_lo < width) & (row_hi >= 0) & (row_lo < height)
    # Only pixels on the image count: clipping bounds the work for absurd guesses.
    col_lo, col_hi = np.clip(col_lo, 0, width - 1), np.clip(col_hi, 0, width - 1)
    row_lo, row_hi = np.clip(row_lo, 0, height - 1), np.clip(row_hi, 0, height - 1)
    return valid, np.stack([col_lo, col_hi, row_lo, row_hi], axis=1)


def batches(valid: np.ndarray, bounds: np.ndarray, n_par: int):
    """
    Return valid spots in batches of similar window size (less padding).

    A batch's windows are padded to its tallest and widest: a batch holds at most
    _MAX_WINDOW_ELEMENTS padded window elements (spots x (parameters + 1) x pixels) and, beyond
    _PADDING_FREE_PIXELS padded pixels, at most _MAX_PADDING times its own windows' pixels (the
    model's cost grows with the padded size: one long streak among hundreds of small spots would
    make them all its size; a few small batches would each pay the solver's fixed cost).
    """
    cols = bounds[:, 1] - bounds[:, 0] + 1
    rows = bounds[:, 3] - bounds[:, 2] + 1
    pixels = cols * rows
    order = np.flatnonzero(valid)
    order = order[np.lexsort((pixels[order], np.maximum(rows, cols)[order]))]
    batch: list[int] = []
    own = top = wide = 0
    for spot in order.tolist():
        grown_top, grown_wide = max(top, int(rows[spot])), max(wide, int(cols[spot]))
        padded = (len(batch) + 1) * grown_top * grown_wide
        too_padded = padded > _MAX_PADDING * (own + pixels[spot]) and padded > _PADDING_FREE_PIXELS
        if batch and (padded * (n_par + 1) > _MAX_WINDOW_ELEMENTS or too_padded):
            yield np.array(batch, np.int64)
            batch, own, grown_top, grown_wide = [], 0, int(rows[spot]), int(cols[spot])
        batch.append(spot)
        own, top, wide = own + int(pixels[spot]), grown_top, grown_wide
    if batch:
        yield np.array(batch, np.int64)


def store_batch(result: StreakFit, batch, win: StreakWindows, params, inverse, done, valid, chi2) -> np.ndarray:
    """
    Write x, y, flux, cov, flux_sigma, converged, chi2, dof of a batch.

    Return the 1-sigma errors of all parameters (n, P). Converged: the fit stopped at a
    minimum with a finite covariance, its centre inside its window, a significant flux, on a
    window free of non-finite pixels.
    """
    n = batch.size
    cov = inverse[:, :2, :2]
    variances = np.diagonal(inverse, axis1=1, axis2=2)
    sigmas = np.sqrt(np.where(variances >= 0, variances, np.inf))
    col_lo, col_hi, row_lo, row_hi = win.bounds.T
    x, y, flux = params[:, 0], params[:, 1], params[:, 2]
    result.converged[batch] = (
        done & valid & ~win.bad & np.all(np.isfinite(params), axis=1)
        & np.all(np.isfinite(cov.reshape(n, -1)), axis=1) & (cov[:, 0, 0] > 0) & (cov[:, 1, 1] > 0)
        & (x >= col_lo) & (x <= col_hi) & (y >= row_lo) & (y <= row_hi)
        & (np.maximum(sigmas[:, 0], sigmas[:, 1]) < np.hypot(col_hi - col_lo, row_hi - row_lo))
        & (flux > SIGNIFICANT_FLUX * sigmas[:, 2]))
    result.x[batch] = np.where(valid, x, np.nan)
    result.y[batch] = np.where(valid, y, np.nan)
    result.flux[batch] = np.where(valid, flux, np.nan)
    result.cov[batch] = np.where(valid[:, None, None], cov, np.nan)
    result.flux_sigma[batch] = np.where(valid, sigmas[:, 2], np.nan)
    result.chi2[batch] = np.where(valid & np.isfinite(chi2), chi2, np.nan)
    result.dof[batch] = np.where(valid, win.mask.sum(axis=1) - params.shape[1], np.nan)
    return sigmas


def flux_start(flux0: np.ndarray, win: StreakWindows, noise: float) -> np.ndarray:
    """Return the caller's flux where positive, else the window sum (at least the pixel noise)."""
    window_sum = np.sum(win.data, axis=1, dtype=np.float64)
    return np.where(flux0 > 0, flux0, np.maximum(window_sum, noise))


def set_path_extent(result: StreakFit, path: np.ndarray) -> None:
    """
    Length and angle of fits on the given paths (N, K, 2) [px] (mid-points of K equal slices of the exposure).

    The chord from the first to the last sample times K / (K - 1) (a straight path's full
    length), its direction start to end [rad] (NaN for a path without extent); their sigmas 0
    (given, not fitted); NaN where nothing was fitted.
    """
    n = path.shape[0]
    if path.shape[1] >= 2:  # the samples are mid-points of K slices of the exposure
        chord = (path[:, -1] - path[:, 0]) * path.shape[1] / (path.shape[1] - 1)
    else:
        chord = np.zeros((n, 2))
    length = np.hypot(chord[:, 0], chord[:, 1])
    fitted = np.isfinite(result.x)
    result.length[:] = np.where(fitted, length, np.nan)
    result.length_sigma[:] = np.where(fitted, 0.0, np.nan)
    result.angle[:] = np.where(fitted & (length > 0), np.arctan2(chord[:, 1], chord[:, 0]), np.nan)
    result.angle_sigma[:] = np.where(fitted & (length > 0), 0.0, np.nan)


def flux_scaled_units(p: np.ndarray, noise: float) -> np.ndarray:
    """
    Typical units (n, P) of parameters laid out as (x, y, F) per star [px, px, ADU].

    1 px for positions (and any further parameters), max(|F|, noise) for fluxes.
    """
    units = np.ones_like(p)
    units[:, 2::3] = np.maximum(np.abs(p[:, 2::3]), noise)
    return units


def position_flux_max_step(p: np.ndarray) -> np.ndarray:
    """
    Trust region (n, P) of (x, y, F) per star.

    1 px per iteration for positions, none for fluxes (the model is linear in them).
    """
    limit = np.full_like(p, 1.0)  # px per iteration
    limit[:, 2::3] = np.inf
    return limit


def unconstrained(index: np.ndarray, p: np.ndarray) -> np.ndarray:
    """No feasible set: the parameters as they are."""
    return p
