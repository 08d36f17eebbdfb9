# SPDX-License-Identifier: Apache-2.0
"""
A fainter star hidden on a bright star's slope, found in the residual of the bright star's fit.

A neighbour 2-3 PSF sigmas from a bright star with a tenth of its light makes no second
maximum in the window (detection.measure.secondary_peaks finds none), yet pulls the single-PSF
fit towards it by about f d exp(-d^2 / 4 sigma^2) (f the flux ratio, d the separation): 0.1-0.2
px at f = 0.1, d = 2.5 sigma, many times a bright star's own sigma. The attitude fit leans on
bright stars, so that pull moves the attitude beyond its stated covariance (the stress
campaign's task 1897: HIP 50335, 26,777 e-, with HIP 50319, 2,478 e-, 6.4 px away in a 2.56 px
PSF: 0.15-0.23 px, 7-10 times its sigma).

After the single-star fit, the residual (window minus the fitted PSF, in a window
hidden_window_half wide) is weighted by a star's profile (a matched filter, 2 sigma each way)
and judged against its noise (the model's shot noise and the pixel noise): its strongest
point blend_separation_px to HIDDEN_MAX_SIGMAS from the star and HIDDEN_MIN_Z sigma above
zero is a hidden star when the point reflected through the star's centre holds less than
SYMMETRY_SHARE of it and their difference is HIDDEN_MIN_ASYMMETRY sigma (a PSF the model does
not quite describe leaves residuals symmetric about the centre; a neighbour does not). Only
stars of flux SNR >= HIDDEN_MIN_SNR are searched: a faint star's own sigma covers what such a
neighbour moves it; and only in frames of PSF sigma >= HIDDEN_MIN_SIGMA_PX where at most
HIDDEN_MAX_SHARE of the stars searched (or HIDDEN_MAX_COUNT) show one: real lenses' asymmetric
PSFs (coma) leave such a residual on most stars (a DSLR frame of the real corpus: 119 of 188).
psf.point_fits fits the two jointly.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..config import blend_separation_px
from ..records import FitContext
from ..windows import PsfWindows

HIDDEN_MIN_SNR = 30.0  # flux SNR of the stars searched
HIDDEN_MAX_SIGMAS = 4.0  # farthest neighbour searched [PSF sigma]: beyond, it barely pulls and is a spot of its own
HIDDEN_REACH_SIGMAS = 5.5  # a search window's half-width [PSF sigma]: a neighbour 3 sigma out and its light
HIDDEN_MIN_Z = 5.0  # matched-filtered residual over its noise [sigma]
HIDDEN_MIN_ASYMMETRY = 4.0  # its excess over the reflected point, over their joint noise [sigma]
SYMMETRY_SHARE = 0.5  # the reflected point's share of the candidate's above which it is the PSF's shape
HIDDEN_MIN_SIGMA_PX = 1.0  # narrower PSFs: a neighbour 2 sigma out is a second peak, and pixel phase skews the residual
# A frame where more of its bright stars than this share (and than HIDDEN_MAX_COUNT) show one has
# an asymmetric PSF (coma, a real lens), not neighbours: none is split.
HIDDEN_MAX_SHARE = 0.1
HIDDEN_MAX_COUNT = 2


def hidden_neighbour_peaks(context: FitContext, windows: PsfWindows, x: np.ndarray, y: np.ndarray,
                           model: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return (found (n,), row, col) of a hidden star in each of the n `windows` (module docstring).

    x, y [px]: the star each window is cut around (wider than a fit window: hidden_window_half);
    model (n, S, S) [ADU]: its single round-Gaussian fit over the window. row, col: the
    candidate's pixel in its window (meaningful where found).
    """
    win, valid, col0, row0 = windows
    n, size, _ = win.shape
    if n == 0 or context.sigma < HIDDEN_MIN_SIGMA_PX:
        return np.zeros(n, bool), np.zeros(n, np.int64), np.zeros(n, np.int64)
    sigma, noise, gain = context.sigma, context.noise, context.gain
    use = valid
    residual = np.where(use, win - model, 0.0)
    variance = np.where(use, np.maximum(model, 0.0) / gain + noise * noise, 0.0)
    # Matched filter: the residual weighted by a star's profile, its variance by the profile squared.
    reach = int(np.ceil(2.0 * sigma))
    offsets = np.arange(-reach, reach + 1)
    profile = np.exp(-0.5 * (offsets[:, None] ** 2 + offsets[None, :] ** 2) / (sigma * sigma)).astype(np.float32)
    filtered, filtered_var = _filtered(residual, profile, reach), _filtered(variance, profile * profile, reach)
    z = filtered / np.sqrt(np.maximum(filtered_var, 1e-12))
    cx, cy = x - col0, y - row0
    rr, cc = np.mgrid[0:size, 0:size]
    distance = np.hypot(rr[None] - cy[:, None, None], cc[None] - cx[:, None, None])
    # A pixel inside the window's edge, its reflection too.
    inner = np.zeros((size, size), bool)
    inner[1:-1, 1:-1] = True
    candidate = (use & inner[None] & (distance >= blend_separation_px(sigma, context.rings))
                 & (distance <= HIDDEN_MAX_SIGMAS * sigma) & (z >= HIDDEN_MIN_Z))
    # The filtered residual at the point reflected through the star's centre (bilinear: the centre is
    # sub-pixel, and a steep residual read a pixel off would look asymmetric).
    mirror_r, mirror_c = 2.0 * cy[:, None, None] - rr[None], 2.0 * cx[:, None, None] - cc[None]
    inside = (mirror_r >= 1.0) & (mirror_r <= size - 2.0) & (mirror_c >= 1.0) & (mirror_c <= size - 2.0)
    mirrored, mirrored_var = (_bilinear(a, np.clip(mirror_r, 1.0, size - 2.0), np.clip(mirror_c, 1.0, size - 2.0))
                              for a in (filtered, filtered_var))
    asymmetry = (filtered - mirrored) / np.sqrt(np.maximum(filtered_var + mirrored_var, 1e-12))
    candidate &= inside & (mirrored < SYMMETRY_SHARE * filtered) & (asymmetry >= HIDDEN_MIN_ASYMMETRY)
    score = np.where(candidate, z, -np.inf).reshape(n, -1)
    best = score.argmax(axis=1)
    found = np.isfinite(score[np.arange(n), best])
    if found.sum() > max(HIDDEN_MAX_COUNT, HIDDEN_MAX_SHARE * n):
        found[:] = False
    return found, best // size, best % size


def _filtered(windows: np.ndarray, kernel: np.ndarray, reach: int) -> np.ndarray:
    """Return the (n, S, S) `windows` correlated with `kernel` ((2 reach + 1)^2), zero outside each window."""
    n, size, _ = windows.shape
    stacked = np.zeros((n, size + reach, size), np.float32)  # `reach` zero rows keep the windows apart
    stacked[:, :size] = windows
    out = cv2.filter2D(stacked.reshape(n * (size + reach), size), -1, kernel, borderType=cv2.BORDER_CONSTANT)
    return out.reshape(n, size + reach, size)[:, :size]


def _bilinear(values: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """Return `values` (n, S, S) read at fractional (row, col) (n, S, S), both inside [0, S - 1]."""
    n, size, _ = values.shape
    r0 = np.minimum(np.floor(row).astype(np.int64), size - 2)
    c0 = np.minimum(np.floor(col).astype(np.int64), size - 2)
    fr, fc = row - r0, col - c0
    w = np.broadcast_to(np.arange(n)[:, None, None], row.shape)
    return ((1.0 - fr) * ((1.0 - fc) * values[w, r0, c0] + fc * values[w, r0, c0 + 1])
            + fr * ((1.0 - fc) * values[w, r0 + 1, c0] + fc * values[w, r0 + 1, c0 + 1]))


def hidden_window_half(sigma: float) -> int:
    """Half-width [px] of the window a bright star is searched in for a hidden neighbour (HIDDEN_REACH_SIGMAS)."""
    return int(np.ceil(HIDDEN_REACH_SIGMAS * max(sigma, 1.0)))
