# SPDX-License-Identifier: Apache-2.0
"""
Extended objects: detections far broader than the PSF (clouds, airglow, a lit limb, nebulae).

A real camera's frame holds more than stars: a cloud bank lit from below, stray-light
structure. Detected as spots, their summed flux outranked the stars in the identifier's
brightest-first patterns. A star (or a few blended stars, or a streak) is as narrow as the
PSF across at least one axis and its brightest pixel holds a share of its flux near the
PSF's; an extended object is wide across both axes and its brightest pixel holds a small
share. Both tests, on the candidate's footprint measurements, with margins that keep a
PSF up to ~4x wider than the width in use (a prior not yet replaced by the frame's
estimate) a star.
"""
from __future__ import annotations

from math import erf, sqrt

import numpy as np

from .candidates import Candidates
from .detect import Detections
from ..windows import gather_windows
from .saturation import box_maxima

# Extended: the narrowest second moment above EXTENDED_MIN_WIDTH x sigma^2 (or unmeasured: a
# faint peak) and the brightest pixel's share of the flux under EXTENDED_PEAK_SHARE x a
# centred point's. Measured on an 8-bit real frame's cloud structures: 14-110x and 0.01-0.045x;
# a star of 3-4x the PSF width in use: 9-16x and 0.07-0.12x; a blend of three stars: ~0.3x.
EXTENDED_MIN_WIDTH = 6.0
EXTENDED_PEAK_SHARE = 0.06
EXTENDED_MIN_SNR = 10.0  # below this the peak pixel is too noisy to judge by
EXTENDED_NEAR_TOP = 0.1  # share of the range above the background below the frame's brightest pixel
# A star on an extended object: its peak stands this share of its height above the background
# above the object's level in a ring ONTOP_RING_PX wide just outside the PSF (3 sigma + 1 px).
ONTOP_EXCESS = 0.5
ONTOP_RING_PX = 1.5
ONTOP_MIN_SIGMA = 10.0


def centred_point_share(sigma_px: float) -> float:
    """Share of a pixel-integrated round Gaussian's flux in its pixel when centred on it [-]."""
    return erf(0.5 / (sqrt(2.0) * max(sigma_px, 1e-3))) ** 2


def extended_candidates(cand: Candidates, sigma_px: float, saturated: np.ndarray, image: np.ndarray,
                        det: Detections) -> np.ndarray:
    """
    Which candidates are extended objects (bool per candidate) under a PSF of `sigma_px` [px].

    Saturated ones (their peak is clipped; `saturated` bool per candidate), those whose peak
    reads within EXTENDED_NEAR_TOP of the frame's brightest pixel and those under
    EXTENDED_MIN_SNR are never judged, nor those a star sits on (star_on_top: a bright star
    in a nebula, whose footprint holds the nebula's light too).
    """
    if cand.x.size == 0 or sigma_px <= 0:
        return np.zeros(cand.x.size, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = cand.peak / cand.flux
    wide = ~np.isfinite(cand.minor) | (cand.minor > EXTENDED_MIN_WIDTH * sigma_px ** 2)
    judged = ~saturated & (cand.snr >= EXTENDED_MIN_SNR) & (cand.flux > 0)
    extended = judged & wide & (share < EXTENDED_PEAK_SHARE * centred_point_share(sigma_px))
    which = np.flatnonzero(extended)
    if which.size == 0:  # the common case: no image-wide work
        return extended
    # Near the frame's ceiling: a clipped star not flagged so (a colour image's grey average of a
    # star clipped in one channel has no flat top), bloomed into a disc wider than the PSF.
    top = float(np.max(image))
    floor = float(np.median(det.background[::4, ::4]))
    extended[which[cand.peak_raw[which] >= top - EXTENDED_NEAR_TOP * max(top - floor, 0.0)]] = False
    which = np.flatnonzero(extended)
    if which.size:
        extended[which[star_on_top(image, det, cand.detection[which], sigma_px)]] = False
    return extended


def star_on_top(image: np.ndarray, det: Detections, detection: np.ndarray, sigma_px: float) -> np.ndarray:
    """
    Whether a point source sits on each detection `detection` (indices in `det`).

    Its brightest pixel stands above the median of the ring ONTOP_RING_PX beyond 3 sigma + 1
    px around it by ONTOP_EXCESS of its height above the background and by ONTOP_MIN_SIGMA x
    the ring's scatter (at least the frame's pixel noise): a star's light falls off within the
    PSF, an extended object's does not.
    """
    height, width = image.shape
    value, row, col = box_maxima(image, det.top[detection], det.left[detection], np.minimum(det.bottom[detection],
                                 height), np.minimum(det.right[detection], width))
    inner = 3.0 * sigma_px + 1.0
    outer = inner + ONTOP_RING_PX
    half = int(np.ceil(outer))
    raw, valid = gather_windows(image, col - half, row - half, 2 * half + 1)
    offsets = np.arange(2 * half + 1) - half
    radius = np.hypot(offsets[:, None], offsets[None, :])
    ring = valid & ((radius >= inner) & (radius < outer))[None]
    level, spread = np.full(detection.size, np.inf), np.full(detection.size, np.inf)
    for k, (w, m) in enumerate(zip(raw, ring)):
        if m.any():
            level[k] = np.median(w[m])
            spread[k] = 1.4826 * np.median(np.abs(w[m] - level[k]))
    background = det.background_at(col.astype(float), row.astype(float))
    height_above, excess = value - background, value - level
    # Significant too: a noise spike on a bright, textured cloud is a sharp peak as well.
    return ((height_above > 0) & (excess >= ONTOP_EXCESS * height_above)
            & (excess >= ONTOP_MIN_SIGMA * np.maximum(spread, det.noise_adu)))
