# SPDX-License-Identifier: Apache-2.0
"""
The width test per peak of a blended footprint: which of its peaks are stars.

A star sharing one detection footprint with a cosmic-ray track or with a neighbour star
makes a long footprint that the width test (extract._shape_defects) judges as a whole and
can reject as a track, the star with it. Here each peak of such a footprint is measured on
its own: the pixels around it (nearer to it than to the footprint's other peaks), their
second moments about the peak. A peak at least as wide as the PSF allows is a star
(kept, fitted jointly with the others); a thinner one is the track (fitted with the stars so
that it does not bias them, then dropped: point_fits.fit_blends).
"""
from __future__ import annotations

import math

import numpy as np

from .detect import Detections

PEAK_RADIUS_SIGMAS = 2.5  # pixels within this many PSF sigmas of a peak are its own
MIN_PEAK_RADIUS_PX = 2.0
# A Gaussian cut at 2.5 sigma keeps 0.86 of its second moment: the width limit is scaled by it.
TRUNCATED_MOMENT = 1.0 - 3.125 * math.exp(-3.125) / (1.0 - math.exp(-3.125))


def peak_minor_moments(image: np.ndarray, det: Detections, peaks: np.ndarray, sigma: float,
                       gain: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return the narrowest second moment [px^2], SNR [-] and centre (K, 2) [px] of each of a footprint's peaks (K, 2).

    From the background-subtracted pixels within max(MIN_PEAK_RADIUS_PX, PEAK_RADIUS_SIGMAS x
    sigma) of the peak and nearer to it than to any other peak; moments about the peak pixel's
    centre of gravity. A peak with no positive flux there gets minor 0 and SNR 0. The second
    moment is TRUNCATED_MOMENT x sigma^2 for a Gaussian star of 1-sigma `sigma` [px].
    """
    height, width = image.shape
    radius = max(MIN_PEAK_RADIUS_PX, PEAK_RADIUS_SIGMAS * sigma)
    half = int(math.ceil(radius))
    peaks = np.asarray(peaks, float)
    minor = np.zeros(len(peaks))
    snr = np.zeros(len(peaks))
    centre = peaks.copy()
    noise2 = det.noise_adu ** 2
    background = det.background_at(peaks[:, 0], peaks[:, 1])
    for k, (px, py) in enumerate(peaks):
        col, row = int(round(px)), int(round(py))
        c0, c1 = max(col - half, 0), min(col + half + 1, width)
        r0, r1 = max(row - half, 0), min(row + half + 1, height)
        xx = np.arange(c0, c1, dtype=float)[None, :]
        yy = np.arange(r0, r1, dtype=float)[:, None]
        own = (xx - px) ** 2 + (yy - py) ** 2
        inside = own <= radius * radius
        for j, (qx, qy) in enumerate(peaks):
            if j != k:
                inside &= own < (xx - qx) ** 2 + (yy - qy) ** 2
        values = np.where(inside, image[r0:r1, c0:c1] - background[k], 0.0)
        flux = float(values.sum())
        if flux <= 0.0:
            continue
        snr[k] = flux / math.sqrt(np.count_nonzero(inside) * noise2 + flux / gain)
        mx, my = float((values * xx).sum()) / flux, float((values * yy).sum()) / flux
        centre[k] = mx, my
        dx, dy = xx - mx, yy - my
        sxx, syy, sxy = ((values * dx * dx).sum() / flux, (values * dy * dy).sum() / flux,
                         (values * dx * dy).sum() / flux)
        minor[k] = 0.5 * (sxx + syy) - math.sqrt(0.25 * (sxx - syy) ** 2 + sxy ** 2)
    return minor, snr, centre
