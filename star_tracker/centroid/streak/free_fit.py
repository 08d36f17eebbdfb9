# SPDX-License-Identifier: Apache-2.0
"""
Free fit of straight streaks.

The PSF swept uniformly along a segment of fitted centre, flux, length and direction, seeded
from the spots' moments (no body rate needed). Windows are cut here; the fit itself is
compiled (streak.free_fit_kernel), one spot at a time.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .levenberg_marquardt import DECREMENT_TOLERANCE, REWEIGHT_STEPS, inverse_fisher
from .smear import segment_length
from .fit_common import (PSF_RADIUS_SIGMA, StreakFit, StreakFitSetup, StreakImage, batches, check_common_inputs,
                         check_excluded, flux_scaled_units, flux_start, store_batch, window_bounds)
from .free_fit_kernel import FreeFitSettings, fit_segments
from .model import StreakWindows, cut_windows


def fit_streaks(image: StreakImage, x0, y0, flux0, length0, angle0, iterations: int = 30) -> StreakFit:
    """
    Fit straight streaks (the PSF swept uniformly along a segment) to a background- subtracted image.

    All spots at once.

    image: the residual (H, W) image minus background [ADU], the PSF sigma [px], the pixel noise
    and gain, the excluded pixels (StreakImage). x0, y0: (N,) initial streak centres [px];
    flux0: (N,) initial total fluxes [ADU] (<= 0 or NaN: the window sum); length0: (N,)
    initial lengths [px], e.g. sqrt(max(12 (major moment - sigma^2), 0)); angle0: (N,)
    initial directions [rad] from +x toward +y (the moments' major axis). NaN length0 or
    angle0: a window for a point-like spot and a start from its moments. iterations: at most
    this many Levenberg-Marquardt steps per spot.

    Model: F times the PSF (module docstring) averaged along the segment of length L at angle
    theta centred on (x, y): parameters (x, y, F, L, theta). The centre is the mid-exposure
    position when the image moves at constant speed; the perspective speeds the image up
    away from the boresight, which moves the centre toward the faster end by up to
    L^2 (pixel scale [rad/px]) tan(off-axis angle) / 4 (~0.006 px for 40 px streaks in a
    15 deg field, more than the noise above SNR ~500): fit_streaks_on_path models it when
    the rate is known. Window: the
    axis-aligned rectangle around the guessed segment (length0 + max(2 px, 10 %) for the
    guess's error) grown by 4 sigma + 1 px on every side; pixels outside it, off the image
    or non-finite are not used. L >= 0: the model is even in L (symmetric nodes), so
    L -> |L| is exact. Near L = 0 the angle is undefined: the fit starts at L >= sigma / 2
    (off the saddle at 0), a damping floor keeps the systems solvable, the angle comes out
    NaN when L < 2 length_sigma and (x, y) is the PSF fit. A spot with unusable inputs or
    data is returned unconverged (NaN where nothing could be fitted); others are unaffected.
    """
    sigma, noise, gain = image.sigma, image.noise, image.gain
    residual, (x0, y0, flux0, length0, angle0) = check_common_inputs(image.residual, sigma, noise, gain, iterations,
                                                                     x0, y0, flux0, length0, angle0)
    excluded = check_excluded(image.excluded, residual)
    n = x0.size
    result = StreakFit.failed(n)
    valid = np.isfinite(x0) & np.isfinite(y0) & (np.abs(x0) < 1e7) & (np.abs(y0) < 1e7)
    guess_ok = np.isfinite(length0) & np.isfinite(angle0)
    length_w = np.where(guess_ok, np.maximum(length0, 0.0), 0.0)
    length_w = length_w + np.maximum(2.0, 0.1 * length_w)
    angle_w = np.where(guess_ok, angle0, 0.0)
    reach = PSF_RADIUS_SIGMA * sigma + 1.0
    half_x = 0.5 * length_w * np.abs(np.cos(angle_w)) + reach
    half_y = 0.5 * length_w * np.abs(np.sin(angle_w)) + reach
    cx, cy = np.round(np.where(valid, x0, 0.0)), np.round(np.where(valid, y0, 0.0))
    valid, bounds = window_bounds(residual, valid, cx - half_x, cx + half_x, cy - half_y, cy + half_y)
    setup = StreakFitSetup(residual, excluded, sigma, noise, gain, iterations)
    start = _FreeStart(x0, y0, flux0, length0, angle0, guess_ok)
    with np.errstate(all="ignore"):  # degenerate spots end up non-finite or unconverged, not as warnings
        for batch in batches(valid, bounds, 5):
            _fit_free_batch(setup, batch, bounds[batch], start.take(batch), result)
    return result


def _window_moments(win: StreakWindows):
    """Major second moment [px^2] and its axis angle [rad] of the positive pixels of each window."""
    n = win.data.shape[0]
    c = np.broadcast_to(np.arange(win.n_cols, dtype=float)[None, None, :], (n, win.n_rows, win.n_cols)).reshape(n, -1)
    r = np.broadcast_to(np.arange(win.n_rows, dtype=float)[None, :, None], (n, win.n_rows, win.n_cols)).reshape(n, -1)
    w = np.maximum(win.data, 0.0) * win.mask
    total = np.maximum(w.sum(axis=1, dtype=np.float64), 1e-300)
    cx, cy = (w * c).sum(axis=1) / total, (w * r).sum(axis=1) / total
    dx, dy = c - cx[:, None], r - cy[:, None]
    mxx, myy, mxy = ((w * dx * dx).sum(1) / total, (w * dy * dy).sum(1) / total, (w * dx * dy).sum(1) / total)
    major = 0.5 * (mxx + myy) + np.sqrt(0.25 * (mxx - myy) ** 2 + mxy ** 2)
    return major, 0.5 * np.arctan2(2 * mxy, mxx - myy)


class _FreeStart(NamedTuple):
    """
    Starting values per spot (n,).

    x0, y0 [px], flux0 [ADU], length0 [px], angle0 [rad], guess_ok (length0 and angle0
    usable; else the window's moments are the start).
    """

    x0: np.ndarray
    y0: np.ndarray
    flux0: np.ndarray
    length0: np.ndarray
    angle0: np.ndarray
    guess_ok: np.ndarray

    def take(self, index) -> "_FreeStart":
        return _FreeStart(*(a[index] for a in self))


def _fit_free_batch(setup: StreakFitSetup, batch: np.ndarray, bounds: np.ndarray, start: _FreeStart,
                    result: StreakFit) -> None:
    """Fit the spots `batch` (window bounds (n, 4), starting values `start`) into `result`."""
    sigma, noise = setup.sigma, setup.noise
    win = cut_windows(setup.residual, *bounds.T, setup.excluded)
    length, angle = start.length0.copy(), start.angle0.copy()
    if not np.all(start.guess_ok):
        major, axis = _window_moments(win)
        length = np.where(start.guess_ok, length, segment_length(major, sigma))
        angle = np.where(start.guess_ok, angle, axis)
    # Longest streak that fits its window (diagonal): beyond it the fit has run away.
    max_length = np.hypot(bounds[:, 1] - bounds[:, 0], bounds[:, 3] - bounds[:, 2]) + 1.0
    # Start off L = 0: there the model is flat in L and theta (a saddle the fit cannot leave).
    length = np.clip(length, 0.5 * sigma, 2.0 * max_length)
    params = np.column_stack([start.x0, start.y0, flux_start(start.flux0, win, noise), length, angle])
    valid = np.all(np.isfinite(params), axis=1) & (win.mask.sum(axis=1) > 6)
    n = batch.size
    own_size = np.stack([bounds[:, 3] - bounds[:, 2] + 1, bounds[:, 1] - bounds[:, 0] + 1], axis=1)
    settings = FreeFitSettings(float(sigma), float(noise), float(setup.gain), int(setup.iterations), REWEIGHT_STEPS,
                               DECREMENT_TOLERANCE)
    solution = fit_segments(win.data.reshape(n, win.n_rows, win.n_cols), win.mask.reshape(n, win.n_rows, win.n_cols),
                            win.origin, own_size.astype(np.int64), np.ascontiguousarray(params, np.float64),
                            max_length.astype(np.float64), valid, settings)
    params = solution.params
    inverse = inverse_fisher(solution.fisher, flux_scaled_units(params, noise))
    sigmas = store_batch(result, batch, win, params, inverse, solution.done, valid, solution.chi2)
    fitted_length, fitted_angle = params[:, 3], params[:, 4]
    result.converged[batch] &= fitted_length <= max_length
    # Direction of an undirected segment in (-pi/2, pi/2]; undefined for an unresolved one.
    direction = np.pi / 2 - np.mod(np.pi / 2 - fitted_angle, np.pi)
    resolved = valid & (fitted_length >= 2.0 * sigmas[:, 3])
    result.length[batch] = np.where(valid, fitted_length, np.nan)
    result.length_sigma[batch] = np.where(valid, sigmas[:, 3], np.nan)
    result.angle[batch] = np.where(resolved, direction, np.nan)
    result.angle_sigma[batch] = np.where(resolved, sigmas[:, 4], np.nan)
