# SPDX-License-Identifier: Apache-2.0
"""
Clipped (saturated) spots.

The level from which a spot's pixels are clipped, from the configured saturation, a flat top
or a fit the brightest pixel undershoots, and the pixels every fit must leave out.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from .candidates import Candidates
from ..psf.gaussian_fit import pixel_integrated_profile
from ..records import FitContext, SpotRows

# Flat top: several pixels of a spot at exactly its brightest raw value, a tie that shot noise
# makes improbable (chance below FLAT_TOP_CHANCE), mark a clipped spot (the sensor's full
# well or ADC ceiling, whatever saturation_adu says). Only spots whose brightest pixel is
# FLAT_TOP_MIN_SIGMA noise sigmas above the background are examined (fainter ones cannot be
# clipped by a sensor whose noise is that far below its ceiling). A false flag costs only the
# information of the pixels left out, never a wrong covariance.
FLAT_TOP_MIN_SIGMA = 50.0
FLAT_TOP_CHANCE = 0.01

# A fitted spot whose model exceeds its brightest raw pixel by more than UNDERSHOOT_SIGMA of
# that pixel's noise has a clipped core (a pixel can only read low when it is clipped).
UNDERSHOOT_SIGMA = 6.0
# ... and, for point fits, whose brightest raw pixel reads within this fraction (of the range
# above the background) of the frame's brightest pixel (an 8-bit JPEG's clipped stars read
# 244-255; a stuck pixel above a lower clip level would hide single-pixel clips: the
# configured saturation_adu still flags those at it).
CLIP_TOP_FRACTION = 0.05


def clip_levels(context: FitContext, spots: Candidates, configured: float) -> np.ndarray:
    """
    Raw level [ADU] from which each spot's pixels are clipped (inf: not saturated).

    The configured saturation level when its brightest raw pixel reaches it, else the value m
    of a flat top in its detection box grown by 2 px: k >= 2 pixels at exactly m, where the
    chance of such a tie is C(near - 1, k - 1) p^(k - 1) < FLAT_TOP_CHANCE, p = 1 ADU times
    the peak density 1 / (sqrt(2 pi) s) of a pixel's value, s = sqrt((m - bg) / gain +
    noise^2) its shot + pixel noise, near = pixels within 2 s of m (a streak's ridge has many
    near the top, a clipped core has only its clipped pixels).
    """
    image, det = context.image, context.det
    n = spots.detection.size
    level = np.full(n, np.inf)
    reached = spots.peak_raw >= configured
    level[reached] = configured
    background = det.background_at(np.nan_to_num(spots.x), np.nan_to_num(spots.y))
    bright = np.flatnonzero(~reached & (spots.peak_raw - background >= FLAT_TOP_MIN_SIGMA * det.noise_adu))
    height, width = image.shape
    for k in bright:
        d = spots.detection[k]
        box = image[max(det.top[d] - 2, 0):min(det.bottom[d] + 2, height),
                    max(det.left[d] - 2, 0):min(det.right[d] + 2, width)]
        top = float(box.max())
        ties = int(np.count_nonzero(box == top))
        if ties < 2:
            continue
        spread = np.sqrt(max(top - background[k], 0.0) / context.gain + det.noise_adu ** 2)
        near = int(np.count_nonzero(box >= top - 2.0 * spread))
        chance = math.comb(near - 1, ties - 1) * (1.0 / (np.sqrt(2.0 * np.pi) * spread)) ** (ties - 1)
        if chance < FLAT_TOP_CHANCE:
            level[k] = top
    return level


BOX_WINDOW_PX = 24  # boxes up to this size are searched together on gathered windows; larger ones one by one


def box_maxima(image: np.ndarray, top: np.ndarray, left: np.ndarray, bottom: np.ndarray,
               right: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Brightest pixel of each box image[top:bottom, left:right] (bottom, right exclusive, inside the image).

    Its value [ADU] (-inf for an empty box), row and column [px]; the first in row-major order
    on ties, as np.argmax on the box. Boxes of at most BOX_WINDOW_PX a side are read as one
    (N, S, S) gather (a Python loop over ~100 small boxes cost ~1 ms a frame).
    """
    n = top.size
    value, row, col = np.full(n, -np.inf), np.zeros(n, np.int64), np.zeros(n, np.int64)
    if n == 0:
        return value, row, col
    height, width = image.shape
    rows, cols = bottom - top, right - left
    limit = min(BOX_WINDOW_PX, height, width)
    small = np.flatnonzero((rows <= limit) & (cols <= limit) & (rows > 0) & (cols > 0))
    if small.size:
        size = int(max(rows[small].max(), cols[small].max()))  # windows of size x size holding each box,
        row0 = np.minimum(top[small], height - size)  # shifted inwards at the image's edges
        col0 = np.minimum(left[small], width - size)
        windows = sliding_window_view(image, (size, size))[row0, col0].astype(np.float64)
        r = row0[:, None] + np.arange(size)  # (k, S) image rows and columns of the windows
        c = col0[:, None] + np.arange(size)
        inside = (((r >= top[small, None]) & (r < bottom[small, None]))[:, :, None]
                  & ((c >= left[small, None]) & (c < right[small, None]))[:, None, :])
        windows[~inside] = -np.inf
        flat = windows.reshape(small.size, -1)
        at = np.argmax(flat, axis=1)
        dr, dc = np.divmod(at, size)
        value[small] = flat[np.arange(small.size), at]
        row[small], col[small] = row0 + dr, col0 + dc
    for k in np.setdiff1d(np.flatnonzero((rows > 0) & (cols > 0)), small):
        box = image[top[k]:bottom[k], left[k]:right[k]]
        at = int(np.argmax(box))
        dr, dc = divmod(at, box.shape[1])
        value[k], row[k], col[k] = box.flat[at], top[k] + dr, left[k] + dc
    return value, row, col


def undershot_peaks(context: FitContext, detection: np.ndarray, fits: SpotRows, path) -> np.ndarray:
    """
    Return the clip level [ADU] of fitted spots clipped in too few pixels for a flat top (inf: none).

    Those are the spots whose brightest raw pixel (in their detection box grown by 2 px) reads
    UNDERSHOOT_SIGMA below the fitted model there. Only spots FLAT_TOP_MIN_SIGMA above the
    background are examined. detection: (N,) the spots' indices in the Detections; fits: their
    fitted x, y, flux; path: (N, K, 2) offsets of fits on a predicted path (the model is their
    mean PSF, the fits' approximation), None for point fits (the pixel-integrated Gaussian).
    """
    image, det, sigma = context.image, context.det, context.sigma
    x, y, flux = fits.x, fits.y, fits.flux
    n = detection.size
    level = np.full(n, np.inf)
    if n == 0:
        return level
    height, width = image.shape
    background = det.background_at(np.nan_to_num(x), np.nan_to_num(y))
    value, row, col = box_maxima(image, np.maximum(det.top[detection] - 2, 0), np.maximum(det.left[detection] - 2, 0),
                                 np.minimum(det.bottom[detection] + 2, height),
                                 np.minimum(det.right[detection] + 2, width))
    above = value - background
    examined = np.flatnonzero(np.isfinite(flux) & (above >= FLAT_TOP_MIN_SIGMA * det.noise_adu))
    if examined.size == 0:
        return level
    r, c, fx, fy, f = row[examined], col[examined], x[examined], y[examined], flux[examined]
    if path is None:
        px, _ = pixel_integrated_profile(c - 0.5, fx, sigma)
        py, _ = pixel_integrated_profile(r - 0.5, fy, sigma)
        model = f * px * py
    else:
        var_eff = sigma * sigma + 1.0 / 12.0
        dx = (c - fx)[:, None] - path[examined, :, 0]
        dy = (r - fy)[:, None] - path[examined, :, 1]
        model = f * np.mean(np.exp(-0.5 * (dx * dx + dy * dy) / var_eff), axis=1) / (2.0 * np.pi * var_eff)
    noise = np.sqrt(np.maximum(model, 0.0) / context.gain + det.noise_adu ** 2)
    hit = above[examined] < model - UNDERSHOOT_SIGMA * noise
    if path is None and hit.any():
        # A clip is the sensor's ceiling: no pixel of the frame reads above it. A point whose peak
        # is well below the frame's brightest pixel undershoots because the star is not the
        # Gaussian's shape (an elliptical or winged PSF), not because it is clipped.
        top = float(np.max(image))
        floor = float(np.median(background[examined]))
        hit &= value[examined] >= top - CLIP_TOP_FRACTION * max(top - floor, 0.0)
    level[examined[hit]] = value[examined[hit]]
    return level


def clipped_pixels(context: FitContext, detection: np.ndarray, level: np.ndarray) -> np.ndarray:
    """
    Return an (H, W) bool mask of the pixels at or above their spot's clip level `level` [ADU], and their spill.

    Within the detection boxes `detection` (indices in the Detections), grown by the PSF's reach
    (any fit reading them leaves them out). On a sensor that blooms (config.sensor_blooms, as
    sim.blooming renders in orbit) the pixels just above and below each clipped run are left
    out too: the last pixel the spill reaches reads more than the PSF puts there. On a sensor
    without blooming they are the PSF's and are fitted.
    """
    image, det = context.image, context.det
    height, width = image.shape
    out = np.zeros(image.shape, bool)
    grow = int(np.ceil(3.0 * context.sigma)) + 2
    for d, value in zip(detection, level):
        rows = slice(max(det.top[d] - grow, 0), min(det.bottom[d] + grow, height))
        cols = slice(max(det.left[d] - grow, 0), min(det.right[d] + grow, width))
        clipped = image[rows, cols] >= value
        out[rows, cols] |= clipped
        if context.config.sensor_blooms:
            # Blooming spills a clipped pixel's excess along its column: the first pixel past
            # either end of a clipped run holds spilled charge no PSF explains.
            out[rows.start + 1:rows.stop, cols] |= clipped[:-1]
            out[rows.start:rows.stop - 1, cols] |= clipped[1:]
    return out
