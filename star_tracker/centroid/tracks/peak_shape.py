# SPDX-License-Identifier: Apache-2.0
"""
The width test per peak of a blended footprint: which of its peaks are stars.

A star sharing one detection footprint with a cosmic-ray track or with a neighbour star
makes a long footprint that the width test (frame_measurement._shape_defects) judges as a whole and
can reject as a track, the star with it. Here each peak of such a footprint is measured on
its own: the pixels around it (nearer to it than to the footprint's other peaks), their
second moments about the peak. A peak at least as wide as the PSF allows is a star
(kept, fitted jointly with the others); a thinner one is the track (fitted with the stars so
that it does not bias them, then dropped: point_fits.fit_blends). Where no fit describes the
star (pulled by the track, a failed fit, a smeared frame's blend) its own pixels' centre of
gravity measures it, model-free.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..detection.detect import Detections
from ..kernel_image import read_only
from .peak_shape_kernel import own_pixel_moments

PEAK_RADIUS_SIGMAS = 2.5  # pixels within this many PSF sigmas of a peak are its own
MIN_PEAK_RADIUS_PX = 2.0
# A Gaussian cut at 2.5 sigma keeps 0.86 of its second moment: the width limit is scaled by it.
TRUNCATED_MOMENT = 1.0 - 3.125 * math.exp(-3.125) / (1.0 - math.exp(-3.125))
# A peak under this share of the width limit is a cosmic-ray track: tracks read 0.15x, real stars'
# cores beside a neighbour >= 0.77x (unh_DSC_0059; blend_screen.blends_beside_tracks).
KEPT_BLEND_TRACK_FRACTION = 0.5
# Ring stars (a defocused PSF, rings=True): a ring's peaks read >= 1.2x the limit, a cosmic-ray track
# 13-16 px from the ring's centre 0.2-0.62x (its disk takes in ring light): measured on the alt
# renderer's annulus frames (sigma 3.4-3.5 px, 180 tracks).
RING_BLEND_TRACK_FRACTION = 0.8
CENTRE_PASSES = 3  # the centre of gravity: the disk re-centred on it this many times
# What the disk's cut leaves in the centre (the track's light inside it, the neighbour's side
# cut off): up to ~0.09 sigma on bench/alt_renderer stars beside tracks, added to its covariance.
CENTRE_SYSTEMATIC_SIGMAS = 0.1


def peak_width_limit(min_width_fraction: float, sigma: float) -> float:
    """
    Return the least narrowest second moment [px^2] of a star's peak on its own pixels.

    min_width_fraction x TRUNCATED_MOMENT x sigma^2; min_width_fraction: CentroidConfig's; sigma:
    the PSF's (narrowest) 1-sigma [px].
    """
    return min_width_fraction * TRUNCATED_MOMENT * sigma ** 2


class PeakShapes(NamedTuple):
    """
    Each peak's own pixels (K peaks).

    minor (K,) narrowest second moment [px^2]; snr (K,) [-]; flux (K,) [ADU]; centre (K, 2)
    centre of gravity (x, y) [px]; centre_cov (K, 2, 2) its covariance: the pixel noise's plus
    (CENTRE_SYSTEMATIC_SIGMAS x sigma)^2 [px^2] (the model-free fallback of a star a fit does not
    describe).
    """

    minor: np.ndarray
    snr: np.ndarray
    flux: np.ndarray
    centre: np.ndarray
    centre_cov: np.ndarray


def peak_minor_moments(image: np.ndarray, det: Detections, peaks: np.ndarray, sigma: float,
                       gain: float, centres: bool = True) -> PeakShapes:
    """
    Measure each of a footprint's peaks (K, 2) (x, y) [px] on its own pixels (PeakShapes).

    From the background-subtracted pixels within max(MIN_PEAK_RADIUS_PX, PEAK_RADIUS_SIGMAS x
    sigma) of the peak and nearer to it than to any other peak: the SNR and the second moments
    about their centre of gravity (TRUNCATED_MOMENT x sigma^2 for a Gaussian star of 1-sigma
    `sigma` [px]); the centre, flux and centre covariance with the disk re-centred on the
    centre of gravity CENTRE_PASSES times (centres False: not measured, flux 0, centre the
    peak, covariance inf). A peak with no positive flux gets minor 0, SNR 0 and flux 0.
    """
    radius = max(MIN_PEAK_RADIUS_PX, PEAK_RADIUS_SIGMAS * sigma)
    peaks = np.ascontiguousarray(peaks, float)
    background = np.asarray(det.background_at(peaks[:, 0], peaks[:, 1]), float)
    minor, snr, flux_of, centre, centre_cov = own_pixel_moments(
        read_only(image), background, peaks, radius, int(math.ceil(radius)), det.noise_adu ** 2, gain,
        CENTRE_PASSES if centres else -1)
    centre_cov += (CENTRE_SYSTEMATIC_SIGMAS * sigma) ** 2 * np.eye(2)  # inf stays inf: not measured
    return PeakShapes(minor, snr, flux_of, centre, centre_cov)
