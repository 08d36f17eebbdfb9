# SPDX-License-Identifier: Apache-2.0
"""
Moments of each blended peak on its own pixels, compiled (numba): peak_shape.peak_minor_moments' loop.

Per peak a few small disks (the first about the peak, then re-centred on the centre of
gravity), too small for numpy's per-call overhead (~0.1 ms a peak in numpy, ~80 peaks a
crowded frame). The sums run in pixel order rather than numpy's pairwise order: the results
agree to the last bits.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..kernel_image import WARM_IMAGE_DTYPES, read_only


@njit(cache=True, inline="always")
def _own(image, background, peaks, k, cx, cy, radius, half, values, inside):
    """
    Fill values/inside with the peak k's pixels in the disk of `radius` about (cx, cy).

    Background-subtracted values [ADU] of the pixels within radius [px] and nearer to peak k
    than to any other peak (others 0, inside False). Returns the window's first column and row
    and its size (columns, rows).
    """
    height, width = image.shape
    col, row = int(round(cx)), int(round(cy))
    c0, c1 = max(col - half, 0), min(col + half + 1, width)
    r0, r1 = max(row - half, 0), min(row + half + 1, height)
    for i in range(r1 - r0):
        y = float(r0 + i)
        for j in range(c1 - c0):
            x = float(c0 + j)
            distance2 = (x - cx) ** 2 + (y - cy) ** 2
            own = distance2 <= radius * radius
            for q in range(peaks.shape[0]):
                if q != k and own:
                    own = distance2 < (x - peaks[q, 0]) ** 2 + (y - peaks[q, 1]) ** 2
            inside[i, j] = own
            values[i, j] = float(image[r0 + i, c0 + j]) - background[k] if own else 0.0
    return c0, r0, c1 - c0, r1 - r0


@njit(cache=True)
def own_pixel_moments(image, background, peaks, radius, half, noise2, gain, centre_passes):
    """
    Return (minor, snr, flux, centre, centre_cov) of each peak (K, 2) (x, y) [px] on its own pixels.

    background (K,) [ADU] at each peak; radius [px] of the disk, half = ceil(radius); noise2 the
    pixel noise variance [ADU^2]; gain [e-/ADU]. minor: the narrowest second moment about the
    centre of gravity [px^2]; centre_passes < 0: centres not measured (flux 0, centre the peak,
    covariance inf), else the disk re-centred on the centre of gravity that many times and the
    centre's noise covariance [px^2] (without the systematic term peak_shape adds).
    """
    count = peaks.shape[0]
    minor, snr, flux_of = np.zeros(count), np.zeros(count), np.zeros(count)
    centre = peaks.copy()
    centre_cov = np.full((count, 2, 2), np.inf)
    size = 2 * half + 1
    values = np.zeros((size, size))
    inside = np.zeros((size, size), np.bool_)
    for k in range(count):
        c0, r0, cols, rows = _own(image, background, peaks, k, peaks[k, 0], peaks[k, 1], radius, half, values, inside)
        flux, pixels, sum_x, sum_y = 0.0, 0, 0.0, 0.0
        for i in range(rows):
            for j in range(cols):
                flux += values[i, j]
                pixels += inside[i, j]
                sum_x += values[i, j] * (c0 + j)
                sum_y += values[i, j] * (r0 + i)
        if flux <= 0.0:
            continue
        snr[k] = flux / math.sqrt(pixels * noise2 + flux / gain)
        mx, my = sum_x / flux, sum_y / flux
        sxx, syy, sxy = 0.0, 0.0, 0.0
        for i in range(rows):
            for j in range(cols):
                dx, dy = c0 + j - mx, r0 + i - my
                sxx += values[i, j] * dx * dx
                syy += values[i, j] * dy * dy
                sxy += values[i, j] * dx * dy
        sxx, syy, sxy = sxx / flux, syy / flux, sxy / flux
        minor[k] = 0.5 * (sxx + syy) - math.sqrt(0.25 * (sxx - syy) ** 2 + sxy ** 2)
        if centre_passes < 0:
            continue
        # The centre: the disk moved onto the centre of gravity (a disk about the peak pixel cuts the
        # star unevenly, pulling the centre toward that pixel).
        for _ in range(centre_passes):
            c0, r0, cols, rows = _own(image, background, peaks, k, mx, my, radius, half, values, inside)
            flux, sum_x, sum_y = 0.0, 0.0, 0.0
            for i in range(rows):
                for j in range(cols):
                    flux += values[i, j]
                    sum_x += values[i, j] * (c0 + j)
                    sum_y += values[i, j] * (r0 + i)
            if flux <= 0.0:
                break
            mx, my = sum_x / flux, sum_y / flux
        if flux <= 0.0:
            continue
        centre[k, 0], centre[k, 1], flux_of[k] = mx, my, flux
        vxx, vxy, vyy = 0.0, 0.0, 0.0
        for i in range(rows):
            for j in range(cols):
                if inside[i, j]:
                    variance = max(values[i, j], 0.0) / gain + noise2
                    dx, dy = c0 + j - mx, r0 + i - my
                    vxx += variance * dx * dx
                    vxy += variance * dx * dy
                    vyy += variance * dy * dy
        f2 = flux * flux
        centre_cov[k, 0, 0], centre_cov[k, 0, 1] = vxx / f2, vxy / f2
        centre_cov[k, 1, 0], centre_cov[k, 1, 1] = vxy / f2, vyy / f2
    return minor, snr, flux_of, centre, centre_cov


def warm_up() -> None:
    """Compile (or load from the cache) the moments for every image dtype (passed read-only, as peak_shape does)."""
    two_peaks = np.array([[3.0, 3.0], [5.0, 4.0]])
    for dtype in WARM_IMAGE_DTYPES:
        own_pixel_moments(read_only(np.zeros((8, 8), dtype)), np.zeros(2), two_peaks, 2.0, 2, 1.0, 1.0, 1)
