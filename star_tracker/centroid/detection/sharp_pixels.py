# SPDX-License-Identifier: Apache-2.0
"""
Pixels sharper than the PSF inside wide stars' fit windows: hot pixels on starlight.

The 4-neighbour hot-pixel test (measure.clean_hot_pixels) asks a pixel to outshine its
brightest neighbour by twice what the PSF allows: on a wide star's slope, where that neighbour
is uphill, a hot pixel must be brighter than the starlight under it to be seen, and one that is
not pulls the fit with no trace in its covariance (bench/alt_renderer.py, Gaussian 2-2.5 px, hot
pixels of 440 e- on stars of 1.5e4-6e4 e-: mean (error / sigma)^2 2.4-2.7 per axis for the stars
with one in their window).

This test compares a pixel with the mean of its 4 neighbours. Any sum of Gaussians at least
as wide as sigma (a star at any sub-pixel phase, a blend, a streak) has mean4 >= q x value,
with q the ratio at a centred star's peak (1 / measure.star_peak_to_neighbour_ratio); a pixel
above that by SHARP_SIGMAS of the difference's shot + pixel noise is not starlight. Judged at
SHARP_WIDTH_FRACTION of the frame's narrowest PSF width (a real core is sharper than its
fitted Gaussian), only for PSFs of at least MIN_SIGMA_PX (narrower ones: the 4-neighbour test
sees hot pixels) and not for rings (a ring's ridge is sharper than its equivalent width).
"""
from __future__ import annotations

import numpy as np

from ..records import FitContext
from ..windows import gather_windows
from .measure import star_peak_to_neighbour_ratio

MIN_SIGMA_PX = 1.5  # narrower PSFs: the 4-neighbour test (2 x the PSF's peak ratio) already sees hot pixels
SHARP_WIDTH_FRACTION = 0.7  # judged as for a PSF this x the frame's narrowest width [-]
SHARP_SIGMAS = 5.0  # excess over the PSF's sharpest curvature, in the difference's noise sigmas


def sharp_pixels(context: FitContext, x: np.ndarray, y: np.ndarray, half: np.ndarray) -> np.ndarray | None:
    """
    Return a (H, W) bool image of the pixels sharper than the PSF in the windows around spots (x, y) [px].

    half (n,): each window's half size [px] (a streak's reaches along it). None when the test
    does not apply (PSF under MIN_SIGMA_PX, rings) or nothing is found.
    """
    sigma = context.sigma if context.elliptical is None else min(context.sigma, context.elliptical.minor_px)
    if sigma < MIN_SIGMA_PX or context.rings or x.size == 0:
        return None
    q = 1.0 / star_peak_to_neighbour_ratio(SHARP_WIDTH_FRACTION * sigma)
    noise, gain = context.noise, context.gain
    height, width = context.image.shape
    found = np.zeros((height, width), bool)
    cx, cy = np.rint(x).astype(np.int64), np.rint(y).astype(np.int64)
    half = np.asarray(half, np.int64)
    for h in np.unique(half).tolist():
        k = np.flatnonzero(half == h)
        size = 2 * h + 3  # a pixel of room: the window's border pixels judged against their neighbours
        col0, row0 = cx[k] - h - 1, cy[k] - h - 1
        raw, valid = gather_windows(context.image, col0, row0, size)
        plane = context.det.background_plane_at(x[k], y[k], context.config.background_block_px)
        data = np.where(valid, raw - plane.over_window(col0, row0, size), 0.0)
        var = np.maximum(data, 0.0) / gain + noise * noise
        centre = data[:, 1:-1, 1:-1]
        mean4 = 0.25 * (data[:, :-2, 1:-1] + data[:, 2:, 1:-1] + data[:, 1:-1, :-2] + data[:, 1:-1, 2:])
        var4 = (var[:, :-2, 1:-1] + var[:, 2:, 1:-1] + var[:, 1:-1, :-2] + var[:, 1:-1, 2:]) / 16.0
        ok = valid[:, 1:-1, 1:-1] & valid[:, :-2, 1:-1] & valid[:, 2:, 1:-1] & valid[:, 1:-1, :-2] & valid[:, 1:-1, 2:]
        hit = ok & (q * centre - mean4 > SHARP_SIGMAS * np.sqrt(q * q * var[:, 1:-1, 1:-1] + var4))
        s, r, c = np.nonzero(hit)
        found[row0[s] + 1 + r, col0[s] + 1 + c] = True
    return found if found.any() else None
