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

# Extended: the narrowest second moment above EXTENDED_MIN_WIDTH x sigma^2 (or unmeasured: a
# faint peak) and the brightest pixel's share of the flux under EXTENDED_PEAK_SHARE x a
# centred point's. Measured on an 8-bit real frame's cloud structures: 14-110x and 0.01-0.045x;
# a star of 3-4x the PSF width in use: 9-16x and 0.07-0.12x; a blend of three stars: ~0.3x.
EXTENDED_MIN_WIDTH = 6.0
EXTENDED_PEAK_SHARE = 0.06
EXTENDED_MIN_SNR = 10.0  # below this the peak pixel is too noisy to judge by


def centred_point_share(sigma_px: float) -> float:
    """Share of a pixel-integrated round Gaussian's flux in its pixel when centred on it [-]."""
    return erf(0.5 / (sqrt(2.0) * max(sigma_px, 1e-3))) ** 2


def extended_candidates(cand: Candidates, sigma_px: float, saturated: np.ndarray) -> np.ndarray:
    """
    Which candidates are extended objects (bool per candidate) under a PSF of `sigma_px` [px].

    Saturated ones (their peak is clipped; `saturated` bool per candidate) and those under
    EXTENDED_MIN_SNR are never judged.
    """
    if cand.x.size == 0 or sigma_px <= 0:
        return np.zeros(cand.x.size, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = cand.peak / cand.flux
    wide = ~np.isfinite(cand.minor) | (cand.minor > EXTENDED_MIN_WIDTH * sigma_px ** 2)
    judged = ~saturated & (cand.snr >= EXTENDED_MIN_SNR) & (cand.flux > 0)
    return judged & wide & (share < EXTENDED_PEAK_SHARE * centred_point_share(sigma_px))
