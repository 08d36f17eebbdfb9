# SPDX-License-Identifier: Apache-2.0
"""
Fit of streaks on a known path (the smear a body rate predicts, SmearModel.path).

Only the mid-exposure position and the flux are fitted, so curved arcs and uneven speed are
exact.
"""
from __future__ import annotations

from functools import partial
from typing import NamedTuple

import numpy as np

from .levenberg_marquardt import LeastSquaresModel, PixelNoise, inverse_fisher, levenberg_marquardt
from .fit_common import (PSF_RADIUS_SIGMA, StreakFit, StreakFitSetup, StreakImage, batches, check_common_inputs,
                         check_excluded, flux_scaled_units, flux_start, position_flux_max_step, set_path_extent,
                         store_batch, unconstrained, window_bounds)
from .model import PIXEL_VARIANCE, StreakWindows, cut_windows, sample_sums


def fit_streaks_on_path(image: StreakImage, x0, y0, flux0, path, iterations: int = 20) -> StreakFit:
    """
    Fit streaks whose shape is known from the body rate (e.g. SmearModel.path); all spots at once.

    image: the residual image, PSF, noise and excluded pixels (StreakImage); x0, y0, flux0: (N,)
    initial mid-exposure positions [px] and total fluxes [ADU] (<= 0 or NaN: the window sum);
    path: (N, K, 2) offsets [px] of each star's image at K equally spaced times across the
    exposure from its mid-exposure position (a straight line, or an arc under roll);
    iterations as fit_streaks.

    Model: F mean_k PSF(pixel - (c + path[n, k])); only c = (x, y) and F are fitted, so
    curved paths and uneven speed are modelled exactly. The path's shape changes slowly with
    position (by ~ path length x field angle moved): compute it at the guess and, for long
    arcs, again at the fitted position for a second fit. Window: the path's bounding box
    around (x0, y0) grown by 4 sigma + 2 px (1 px for the guess's error). length: the chord
    [px] from the first to the last sample times K / (K - 1), i.e. extended by half a
    sample interval at both ends (a straight path's full length, as fit_streaks and the
    renderer's extent_px report it);
    angle: direction of motion, start to end, in (-pi, pi] (NaN for a path of one sample);
    length_sigma and angle_sigma are 0 (given, not fitted). A spot whose inputs or path are
    not finite is returned unconverged; others are unaffected.
    """
    sigma, noise, gain = image.sigma, image.noise, image.gain
    residual, (x0, y0, flux0) = check_common_inputs(image.residual, sigma, noise, gain, iterations, x0, y0, flux0)
    excluded = check_excluded(image.excluded, residual)
    n = x0.size
    try:
        path = np.asarray(path, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("path must be a numeric (N, K, 2) array of pixel offsets") from None
    if path.ndim != 3 or path.shape[0] != n or path.shape[2] != 2 or path.shape[1] < 1:
        raise ValueError(f"path must have shape (N={n}, K>=1, 2), got {path.shape}")
    result = StreakFit.failed(n)
    valid = (np.isfinite(x0) & np.isfinite(y0) & (np.abs(x0) < 1e7) & (np.abs(y0) < 1e7)
             & np.isfinite(path).all(axis=(1, 2)))
    path = np.where(valid[:, None, None], path, 0.0)
    reach = PSF_RADIUS_SIGMA * sigma + 2.0
    cx, cy = np.round(np.where(valid, x0, 0.0)), np.round(np.where(valid, y0, 0.0))
    valid, bounds = window_bounds(residual, valid, cx + path[:, :, 0].min(axis=1) - reach,
                                  cx + path[:, :, 0].max(axis=1) + reach, cy + path[:, :, 1].min(axis=1) - reach,
                                  cy + path[:, :, 1].max(axis=1) + reach)
    setup = StreakFitSetup(residual, excluded, sigma, noise, gain, iterations)
    start = _PathStart(x0, y0, flux0, path)
    with np.errstate(all="ignore"):  # degenerate spots end up non-finite or unconverged, not as warnings
        for batch in batches(valid, bounds, 3):
            _fit_path_batch(setup, batch, bounds[batch], start.take(batch), result)
    set_path_extent(result, path)
    return result


class _PathStart(NamedTuple):
    """
    Starting values per spot.

    x0, y0 (n,) [px], flux0 (n,) [ADU]; offsets (n, K, 2) its path [px] relative to the
    mid-exposure position.
    """

    x0: np.ndarray
    y0: np.ndarray
    flux0: np.ndarray
    offsets: np.ndarray

    def take(self, index) -> "_PathStart":
        return _PathStart(*(a[index] for a in self))


def _fit_path_batch(setup: StreakFitSetup, batch: np.ndarray, bounds: np.ndarray, start: _PathStart,
                    result: StreakFit) -> None:
    """Fit the spots `batch` (window bounds (n, 4), starting values `start`) into `result`."""
    noise = setup.noise
    win = cut_windows(setup.residual, *bounds.T, setup.excluded)
    model = _path_model(win, start.offsets, setup.sigma, noise)
    params = np.column_stack([start.x0, start.y0, flux_start(start.flux0, win, noise)])
    valid = np.all(np.isfinite(params), axis=1) & (win.mask.sum(axis=1) > 4)
    params, normal, done, chi2 = levenberg_marquardt(model, params, win, valid, PixelNoise(noise, setup.gain),
                                                     setup.iterations)
    store_batch(result, batch, win, params, inverse_fisher(normal, model.scale_of(params)), done, valid, chi2)


def _path_model(win: StreakWindows, offsets: np.ndarray, sigma: float, noise: float) -> LeastSquaresModel:
    """
    Return the model (x, y, F) of one star per window moving along `offsets` (n, K, 2) [px].

    The model is the mean of K PSF copies.
    """
    weights = np.full(offsets.shape[:2], 1.0 / offsets.shape[1])
    var_eff = sigma * sigma + PIXEL_VARIANCE
    scale = 1.0 / np.sqrt(2.0 * var_eff)
    amplitude_unit = 1.0 / (2.0 * np.pi * var_eff)

    def evaluate(index, p):
        xc, yc, f = p.T
        sx = (xc - win.origin[index, 0])[:, None] + offsets[index, :, 0]
        sy = (yc - win.origin[index, 1])[:, None] + offsets[index, :, 1]
        sums = sample_sums(win, sx, sy, weights[index], scale)  # shape, gx', gy'
        a = f * amplitude_unit
        mix = np.zeros((index.size, 4, 3), np.float32)  # jacobian rows (x, y, F) and the model
        mix[:, 0, 1] = mix[:, 1, 2] = a * (2.0 * scale)
        mix[:, 2, 0] = amplitude_unit
        mix[:, 3, 0] = a
        return np.matmul(mix, sums)

    return LeastSquaresModel(evaluate, position_flux_max_step, unconstrained, partial(flux_scaled_units, noise=noise))
