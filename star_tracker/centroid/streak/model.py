# SPDX-License-Identifier: Apache-2.0
"""
The streak model's pixels.

Windows cut from a residual image, and the separable PSF copies summed along a streak's path (the
model and its derivatives for the streak fits).

PSF model: the pixel-integrated Gaussian of 1-sigma `sigma` [px] is approximated by a
Gaussian of variance sigma^2 + 1/12 px^2 (the pixel's box variance added) evaluated at the
pixel centres. It matches the pixel integral to second order and differs from it by < 0.2 %
of the peak for sigma = 1 px (the box's excess kurtosis, an even error that moves no
centre; the fits reach the Cramer-Rao bound of the exact model, see test/centroid/test_streak.py),
and it needs exp only, ~5x cheaper than erf. A PSF narrower than narrow_width.NARROW_PX
(undersampled: the approximation moved 0.4 px streaks' centres by a few of their stated
sigmas, chi^2 of 2-7 against the independent renderer's truth) gets the exact pixel integral
(normal CDF differences; pixel_integrated). A streak is a weighted sum of PSF copies along
its path: Simpson's rule with nodes <= 1 PSF sigma apart for a straight segment (< 1 % of
the peak from the continuous segment, at its ends; symmetric, so no position error, and
lengths come out within 0.01 px; the free fit's, compiled in streak.free_fit_kernel), the given
samples for a known path. Each copy is separable in x and y, so a window's model and its
derivatives are batched matrix products sum_k w_k py_k px_k^T, as in the renderer; the
profiles are float32 in window coordinates.

Image convention: pixel (0, 0) is the centre of the top-left pixel; x = column, y = row [px].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from .narrow_width import NARROW_PX

PIXEL_VARIANCE = 1.0 / 12.0  # a pixel's box variance [px^2]
_FLOOR = float(np.exp(-30.0))  # the profiles' floor, as exp(-min(v^2, 30))


@dataclass
class StreakWindows:
    """
    Pixel windows of a batch of spots, padded to one size (R rows x C columns).

    Origin (n, 2) = pixel (col, row) of each window's first element [px]; data (n, R*C) [ADU]
    (0 where masked), mask (n, R*C) (1 = use), float32; bad (n,) True if a non-finite pixel
    fell inside the spot's own window; bounds (n, 4) col_lo, col_hi, row_lo, row_hi of its
    own window [px].
    """

    n_rows: int
    n_cols: int
    origin: np.ndarray
    data: np.ndarray
    mask: np.ndarray
    bad: np.ndarray
    bounds: np.ndarray


def cut_windows(residual: np.ndarray, col_lo, col_hi, row_lo, row_hi, excluded=None) -> StreakWindows:
    """
    Windows [col_lo, col_hi] x [row_lo, row_hi] (integer pixel bounds, inclusive) padded to the largest.

    Pixels outside the image, outside the spot's own window, non-finite or `excluded` ((H, W)
    bool, e.g. clipped at the full well; None = none) are masked.
    """
    height, width = residual.shape
    n_cols = int(np.max(col_hi - col_lo)) + 1
    n_rows = int(np.max(row_hi - row_lo)) + 1
    cols = col_lo[:, None] + np.arange(n_cols)[None, :]
    rows = row_lo[:, None] + np.arange(n_rows)[None, :]
    col_ok = (cols <= col_hi[:, None]) & (cols >= 0) & (cols < width)
    row_ok = (rows <= row_hi[:, None]) & (rows >= 0) & (rows < height)
    flat = np.clip(rows, 0, height - 1)[:, :, None] * width + np.clip(cols, 0, width - 1)[:, None, :]
    data = np.take(residual.reshape(-1), flat).astype(np.float32)
    use = row_ok[:, :, None] & col_ok[:, None, :]
    if excluded is not None:
        use &= ~np.take(excluded.reshape(-1), flat)
    finite = np.isfinite(data)
    bad = ~np.all(finite | ~use, axis=(1, 2))
    use &= finite
    data[~use] = 0.0
    n = cols.shape[0]
    return StreakWindows(n_rows, n_cols, np.stack([col_lo, row_lo], axis=1).astype(np.float64), data.reshape(n, -1),
                         use.reshape(n, -1).astype(np.float32), bad, np.stack([col_lo, col_hi, row_lo, row_hi], axis=1))


def _profiles(count: int, positions: np.ndarray, scale: float, log_weights, g_out, vg_out, transposed: bool):
    """
    Gaussian profiles over the pixel centres 0..count-1 of a window for K sample positions p (n, K) [px, window frame].

    Written to g_out and vg_out (float32): g = w exp(-v^2) and v g, v = (c - p) scale, scale =
    1 / sqrt(2 var), w the sample weights (log_weights (n, K), or None for 1); dg/dp = 2 scale
    (v g). Shapes (n, K, count), or (n, count, K) if transposed. Window-frame coordinates (<
    1e3 px) keep float32 to 1e-4 px.
    """
    if pixel_integrated(scale):
        _integrated_profiles(count, positions, scale, log_weights, g_out, vg_out, transposed)
        return
    centres = np.arange(count, dtype=np.float32) * np.float32(scale)
    p = (positions * scale).astype(np.float32)
    v = centres[None, :, None] - p[:, None, :] if transposed else centres[None, None, :] - p[:, :, None]
    exponent = v * v
    # Floor at exp(-30) ~ 1e-13: float32 denormals (below exp(-87), and their products in the
    # sums) are ~100x slower to compute with; the floor's light is negligible.
    np.minimum(exponent, np.float32(30.0), out=exponent)
    if log_weights is None:
        np.negative(exponent, out=exponent)
    else:
        log_weights = log_weights.astype(np.float32)
        np.subtract(log_weights[:, None, :] if transposed else log_weights[:, :, None], exponent, out=exponent)
    np.exp(exponent, out=g_out)
    np.multiply(v, g_out, out=vg_out)


def pixel_integrated(scale: float) -> bool:
    """Whether the PSF of scale = 1 / sqrt(2 (sigma^2 + 1/12)) [1/px] is narrower than NARROW_PX (exact profiles)."""
    return 0.5 / (scale * scale) - PIXEL_VARIANCE < NARROW_PX * NARROW_PX


def _integrated_profiles(count: int, positions: np.ndarray, scale: float, log_weights, g_out, vg_out,
                         transposed: bool):
    """
    Write _profiles' g and v g for a PSF narrower than NARROW_PX: the Gaussian integrated over each pixel.

    g = w sqrt(pi) / scale (Phi(u+) - Phi(u-)), u+- = (c +- 1/2 - p) / sigma, sigma^2 = 1 / (2
    scale^2) - 1/12: the pixel's share of a unit copy in the units of the Gaussian profile
    (whose sum over pixels is sqrt(pi) / scale), so that the callers' amplitude (scale^2 / pi
    per unit flux) and their derivative 2 scale (v g) hold; v g = (dg/dp) / (2 scale). Floored
    as _profiles.
    """
    sigma = float(np.sqrt(max(0.5 / (scale * scale) - PIXEL_VARIANCE, 1e-6)))
    centres = np.arange(count, dtype=np.float64)
    offset = centres[None, :, None] - positions[:, None, :] if transposed else \
        centres[None, None, :] - positions[:, :, None]
    upper, lower = (offset + 0.5) / sigma, (offset - 0.5) / sigma
    norm = np.sqrt(np.pi) / scale
    share = norm * (ndtr(upper) - ndtr(lower))
    slope = norm * (np.exp(-0.5 * lower * lower) - np.exp(-0.5 * upper * upper)) / (np.sqrt(2.0 * np.pi) * sigma)
    if log_weights is not None:
        weights = np.exp(log_weights)
        weights = weights[:, None, :] if transposed else weights[:, :, None]
        share, slope = share * weights, slope * weights
        floor = weights * _FLOOR
    else:
        floor = _FLOOR
    g_out[...] = np.maximum(share, floor)
    vg_out[...] = slope / (2.0 * scale)


def sample_sums(win: StreakWindows, sx: np.ndarray, sy: np.ndarray, weights: np.ndarray, scale: float):
    """
    Return weighted sums over the K samples of a streak of separable PSF copies, for every window pixel.

    Unnormalized (see _profiles): (n, 3, R*C) float32 holding shape = sum w gy gx,
    gx' = sum w gy (v g)_x, gy' = sum w (v g)_y gx (the x and y derivatives / 2 scale). sx,
    sy: (n, K) sample positions [px] in the window frame; weights: (n, K) >= 0, summing to
    1 per spot. Batched matrix products do every sum over samples.
    """
    n_rows, n_cols = win.n_rows, win.n_cols
    n, k = sx.shape
    x_profiles = np.empty((n, 2, k, n_cols), np.float32)  # g, v g along x
    _profiles(n_cols, sx, scale, None, x_profiles[:, 0], x_profiles[:, 1], transposed=False)
    gy = np.empty((n, n_rows, k), np.float32)
    vgy = np.empty((n, n_rows, k), np.float32)  # v g along y
    _profiles(n_rows, sy, scale, np.log(weights), gy, vgy, transposed=True)
    sums = np.empty((n, 3, n_rows, n_cols), np.float32)
    np.matmul(gy, x_profiles[:, 0], out=sums[:, 0])  # shape
    np.matmul(gy, x_profiles[:, 1], out=sums[:, 1])  # gx'
    np.matmul(vgy, x_profiles[:, 0], out=sums[:, 2])  # gy'
    return sums.reshape(n, 3, -1)
