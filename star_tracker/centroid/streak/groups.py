# SPDX-License-Identifier: Apache-2.0
"""
Several stars on one known path shape (streaks merged into one detection, or a neighbour's streak in a spot's window).

The matched-filter search for one more star in what a fit leaves, and the joint fit of a
group of stars.
"""
from __future__ import annotations

from functools import partial

import numpy as np
from scipy.fft import next_fast_len

from .levenberg_marquardt import LeastSquaresModel, PixelNoise, inverse_fisher, levenberg_marquardt
from .fit_common import (PSF_RADIUS_SIGMA, StreakFit, StreakFitSetup, StreakImage, batches, check_excluded,
                         flux_scaled_units, position_flux_max_step, set_path_extent, store_batch, unconstrained,
                         window_bounds)
from .model import PIXEL_VARIANCE, StreakWindows, cut_windows, sample_sums


def _path_windows(residual, x, y, path, reach, valid):
    """
    Integer bounds of windows covering the paths `path` (n, K, 2) around every centre x, y (n, M) [px].

    Grown by `reach` [px] (see window_bounds).
    """
    cx, cy = np.round(np.where(valid[:, None], x, 0.0)), np.round(np.where(valid[:, None], y, 0.0))
    return window_bounds(residual, valid, cx.min(axis=1) + path[:, :, 0].min(axis=1) - reach,
                         cx.max(axis=1) + path[:, :, 0].max(axis=1) + reach,
                         cy.min(axis=1) + path[:, :, 1].min(axis=1) - reach,
                         cy.max(axis=1) + path[:, :, 1].max(axis=1) + reach)


def _path_model(win: StreakWindows, x, y, flux, offsets, sigma: float) -> np.ndarray:
    """(n, R*C) model [ADU] of one star per window on its path (the fits' PSF model)."""
    var_eff = sigma * sigma + PIXEL_VARIANCE
    scale = 1.0 / np.sqrt(2.0 * var_eff)
    sx = (x - win.origin[:, 0])[:, None] + offsets[:, :, 0]
    sy = (y - win.origin[:, 1])[:, None] + offsets[:, :, 1]
    weights = np.full(offsets.shape[:2], 1.0 / offsets.shape[1])
    shape = sample_sums(win, sx, sy, weights, scale)[:, 0]
    return shape * (flux / (2.0 * np.pi * var_eff))[:, None]


def second_source_on_path(image: StreakImage, x, y, flux, path):
    """
    Find where one more star on the same path shape would best explain what a fit of M stars leaves.

    The fit: x, y, flux (N,) or (N, M) [px, ADU]; path (N, K, 2) as fit_streaks_on_path. In the
    window of the first star (the window fit_streaks_on_path uses), the residual (data - model)
    is correlated with the path's own unit-flux profile t (a matched filter), divided by its
    noise sqrt(sum var t^2) (var = max(data, 0) / gain + noise^2 per pixel). Returns, at the
    peak of that ratio, x, y [px], the template's least-squares flux [ADU] and the ratio (the
    matched-filter SNR of the best extra star), each (N,); NaN where nothing is usable. All
    windows at once (padded to one size, correlations by FFT).
    """
    sigma, noise, gain = image.sigma, image.noise, image.gain
    residual = np.asarray(image.residual)
    excluded = check_excluded(image.excluded, residual)
    x, y, flux = (np.asarray(v, dtype=float).reshape(np.shape(v)[0], -1) for v in (x, y, flux))
    path = np.asarray(path, dtype=float)
    n = x.shape[0]
    out = np.full((4, n), np.nan)
    ok = np.all(np.isfinite(x) & np.isfinite(y) & np.isfinite(flux), axis=1) & np.isfinite(path).all(axis=(1, 2))
    ok, bounds = _path_windows(residual, x[:, :1], y[:, :1], np.where(ok[:, None, None], path, 0.0),
                               PSF_RADIUS_SIGMA * sigma + 2.0, ok)
    use = np.flatnonzero(ok)
    if use.size == 0:
        return out[0], out[1], out[2], out[3]
    win = cut_windows(residual, *bounds[use].T, excluded)
    offsets = path[use]
    model = sum(_path_model(win, x[use, m], y[use, m], flux[use, m], offsets, sigma) for m in range(x.shape[1])
                if np.all(np.isfinite(x[use, m])))
    shape = (use.size, win.n_rows, win.n_cols)
    left = ((win.data - model) * win.mask).reshape(shape)
    variance = ((np.maximum(win.data, 0.0) / gain + noise * noise) * win.mask).reshape(shape)
    template, half = _path_templates(offsets, sigma)
    # Correlation with the template centred: score[c] = sum_u left[c + u - h] t[u], i.e. the
    # full convolution with the flipped template, cropped at (h, h). Transformed at the next
    # sizes with only small prime factors (a prime size, e.g. 43, is pocketfft's slow case);
    # the padding beyond the full convolution is zero and cropped away.
    size = (next_fast_len(win.n_rows + template.shape[1] - 1, real=True),
            next_fast_len(win.n_cols + template.shape[2] - 1, real=True))

    def correlate(image, kernel):
        full = np.fft.irfft2(np.fft.rfft2(image, size) * np.fft.rfft2(kernel[:, ::-1, ::-1], size), size)
        return full[:, half[1]:half[1] + win.n_rows, half[0]:half[0] + win.n_cols]

    score = correlate(left, template)
    spread = correlate(variance, template * template)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where((win.mask.reshape(shape) > 0) & (spread > 0), score / np.sqrt(np.abs(spread)), -np.inf)
    flat = ratio.reshape(use.size, -1)
    best = np.argmax(flat, axis=1)
    found = np.isfinite(flat[np.arange(use.size), best])
    row, col = best // win.n_cols, best % win.n_cols
    keep = use[found]
    out[0, keep] = win.origin[found, 0] + col[found]
    out[1, keep] = win.origin[found, 1] + row[found]
    out[2, keep] = (score.reshape(use.size, -1)[np.arange(use.size), best][found]
                    / np.sum(template * template, axis=(1, 2))[found])
    out[3, keep] = flat[np.arange(use.size), best][found]
    return out[0], out[1], out[2], out[3]


def _path_templates(offsets: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """
    Return each path's unit-flux profile (n, TR, TC) and its half size (x, y) [px].

    The fits' PSF model (variance sigma^2 + 1/12 px^2) on a grid centred on the mid-exposure
    point, one size for all: separable sums over the path samples `offsets` (n, K, 2) [px].
    """
    var_eff = sigma * sigma + PIXEL_VARIANCE
    half = np.ceil(np.max(np.abs(offsets), axis=(0, 1)) + 3.0 * np.sqrt(var_eff)).astype(int)
    gx = np.arange(-half[0], half[0] + 1, dtype=float)
    gy = np.arange(-half[1], half[1] + 1, dtype=float)
    px = np.exp(-0.5 * (gx[None, None, :] - offsets[:, :, 0, None]) ** 2 / var_eff)  # (n, K, TC)
    py = np.exp(-0.5 * (gy[None, None, :] - offsets[:, :, 1, None]) ** 2 / var_eff)  # (n, K, TR)
    template = np.matmul(np.transpose(py, (0, 2, 1)), px)  # (n, TR, TC)
    template /= template.sum(axis=(1, 2), keepdims=True)
    return template, half


def fit_star_groups_on_path(image: StreakImage, x0, y0, flux0, path, iterations: int = 30) -> list[StreakFit]:
    """
    Fit M stars moving on the same path shape jointly.

    Streaks merged into one spot, or a neighbour's streak in its window: x0, y0, flux0 (N, M)
    initial positions [px] and fluxes [ADU], the first star of each group the one whose window
    is fitted (the window fit_streaks_on_path uses for it, so that the chi^2 of the two fits
    compare); path (N, K, 2) and the rest as fit_streaks_on_path. Returns M StreakFit (star m
    of every group) with positions, fluxes and covariances (blocks of the joint inverse Fisher
    matrix: each star's error includes what the others' uncertainty does to it); all carry the
    group's chi2 and dof. converged: the first star's test of fit_streaks_on_path, and finite
    values for the others (whose centres may lie outside the window: only their light inside
    it is used).
    """
    sigma, noise, gain = image.sigma, image.noise, image.gain
    residual = np.asarray(image.residual)
    excluded = check_excluded(image.excluded, residual)
    x0, y0, flux0 = (np.asarray(v, dtype=float) for v in (x0, y0, flux0))
    n, m_stars = x0.shape
    path = np.asarray(path, dtype=float)
    fits = [StreakFit.failed(n) for _ in range(m_stars)]
    if n == 0:
        return fits
    valid = (np.all(np.isfinite(x0) & np.isfinite(y0) & np.isfinite(flux0), axis=1)
             & np.isfinite(path).all(axis=(1, 2)))
    path = np.where(valid[:, None, None], path, 0.0)
    valid, bounds = _path_windows(residual, x0[:, :1], y0[:, :1], path, PSF_RADIUS_SIGMA * sigma + 2.0, valid)
    setup = StreakFitSetup(residual, excluded, sigma, noise, gain, iterations)
    with np.errstate(all="ignore"):  # degenerate groups end up non-finite or unconverged
        for batch in batches(valid, bounds, 3 * m_stars):
            _fit_group_batch(setup, batch, bounds[batch], (x0[batch], y0[batch], flux0[batch], path[batch]), fits)
    every = np.all([f.converged for f in fits], axis=0)
    for result in fits:
        result.converged[:] = every
        set_path_extent(result, path)
    return fits


def _fit_group_batch(setup: StreakFitSetup, batch: np.ndarray, bounds: np.ndarray, start,
                     fits: list[StreakFit]) -> None:
    """
    Fit the groups `batch` into `fits` (one StreakFit per star of the groups).

    batch: window bounds (n, 4); start: x0, y0, flux0 (n, M) and the paths (n, K, 2).
    """
    x0, y0, flux0, offsets = start
    m_stars = x0.shape[1]
    n_par = 3 * m_stars
    win = cut_windows(setup.residual, *bounds.T, setup.excluded)
    model = _group_model(win, offsets, setup.sigma, setup.noise, m_stars)
    params = np.stack([x0, y0, flux0], axis=2).reshape(batch.size, n_par)
    ok = np.all(np.isfinite(params), axis=1) & (win.mask.sum(axis=1) > n_par + 1)
    params, normal, done, chi2 = levenberg_marquardt(model, params, win, ok, PixelNoise(setup.noise, setup.gain),
                                                     setup.iterations)
    inverse = inverse_fisher(normal, model.scale_of(params))
    for m, result in enumerate(fits):
        block = slice(3 * m, 3 * m + 3)
        store_batch(result, batch, win, params[:, block], inverse[:, block, block], done, ok, chi2)
        result.dof[batch] -= n_par - 3  # the group's parameters
        if m > 0:  # a neighbour: only its light in the window matters
            result.converged[batch] = (done & ok & ~win.bad & np.all(np.isfinite(params), axis=1)
                                       & np.isfinite(result.cov[batch]).all(axis=(1, 2))
                                       & (result.cov[batch, 0, 0] > 0) & (result.cov[batch, 1, 1] > 0))


def _group_model(win: StreakWindows, offsets: np.ndarray, sigma: float, noise: float,
                 m_stars: int) -> LeastSquaresModel:
    """
    Return the model (x_m, y_m, F_m) of M stars per window.

    Each star moves along the window's `offsets` (n, K, 2) [px].
    """
    var_eff = sigma * sigma + PIXEL_VARIANCE
    scale = 1.0 / np.sqrt(2.0 * var_eff)
    amplitude_unit = 1.0 / (2.0 * np.pi * var_eff)
    n_par = 3 * m_stars
    weights = np.full(offsets.shape[:2], 1.0 / offsets.shape[1])

    def evaluate(index, p):
        aug = np.zeros((index.size, n_par + 1, win.data.shape[1]), np.float32)  # jacobian rows, model
        for m in range(m_stars):
            sx = (p[:, 3 * m] - win.origin[index, 0])[:, None] + offsets[index, :, 0]
            sy = (p[:, 3 * m + 1] - win.origin[index, 1])[:, None] + offsets[index, :, 1]
            sums = sample_sums(win, sx, sy, weights[index], scale)  # shape, gx', gy'
            a = (p[:, 3 * m + 2] * amplitude_unit).astype(np.float32)[:, None]
            aug[:, 3 * m] = a * np.float32(2.0 * scale) * sums[:, 1]
            aug[:, 3 * m + 1] = a * np.float32(2.0 * scale) * sums[:, 2]
            aug[:, 3 * m + 2] = np.float32(amplitude_unit) * sums[:, 0]
            aug[:, n_par] += a * sums[:, 0]
        return aug

    return LeastSquaresModel(evaluate, position_flux_max_step, unconstrained, partial(flux_scaled_units, noise=noise))
