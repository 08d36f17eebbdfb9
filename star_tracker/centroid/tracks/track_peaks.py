# SPDX-License-Identifier: Apache-2.0
"""
Cosmic-ray tracks merged with stars in one footprint: finding the star's peak and the track's.

The candidates' measurement searches an elongated footprint for two peaks (measure.two_peaks)
and blend_screen.blends_beside_tracks judges each peak on its own pixels. Two
arrangements defeat the plain search, and are looked for here (window pixels, all of a batch):
- a track just outside a ring star (a defocused PSF) lies nearer to the ring's brightest
  maximum than the ring's own maxima may lie apart (config.RING_BLEND_SIGMAS): ring_track_peaks;
- a track brighter per pixel than the star beside it holds the footprint's brightest maxima, so
  the star's peak is never tried: star_beside_track_peaks (screened first: track_screen).
Measured on bench/alt_renderer.py frames with tracks drawn on them
(test/centroid/test_stars_beside_tracks*.py).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..config import blend_separation_px
from ..detection.candidate_frame import CandidateFrame
from ..detection.measure import aperture_moments, two_peaks
from .peak_shape import (KEPT_BLEND_TRACK_FRACTION, MIN_PEAK_RADIUS_PX, PEAK_RADIUS_SIGMAS, RING_BLEND_TRACK_FRACTION,
                         peak_minor_moments, peak_width_limit)

# A ring star's track: a maximum this many PSF sigmas from the spot's centre of light (ring_track_peaks).
RING_TRACK_SIGMAS = 3.0
# A star beside a track holding a footprint's two brightest maxima: searched among this many others.
STAR_SEARCH_MAXIMA = 8
# The window screen lets a brightest peak up to this multiple of the track limit through to peak_shape's test.
TRACK_PEAK_MARGIN = 1.5


class PeakSearch(NamedTuple):
    """
    A batch of windows (n, R, C) searched for two peaks (measure.box_sums, two_peaks).

    box, box_var: the box sums [ADU] and their variances; maxima: the boxes that are local
    maxima; threshold: a peak's least box sum [ADU]; col0, row0 (n,): each window's top-left
    image pixel [px].
    """

    box: np.ndarray
    box_var: np.ndarray
    maxima: np.ndarray
    threshold: float
    col0: np.ndarray
    row0: np.ndarray


class FoundPeaks(NamedTuple):
    """Per window (n,): found, two peaks found; rows, cols (n, 2): their window pixels, the brighter first."""

    found: np.ndarray
    rows: np.ndarray
    cols: np.ndarray


def track_screen(data: np.ndarray, valid: np.ndarray, row: np.ndarray, col: np.ndarray, sigma: float,
                 config) -> np.ndarray:
    """
    Whether each window's brightest peak (row, col) may be a track, from its moments on the window (n,).

    Its narrowest second moment (peak_minor_on_windows) under TRACK_PEAK_MARGIN x
    KEPT_BLEND_TRACK_FRACTION x the width limit (config: CentroidConfig; sigma [px]).
    """
    limit = peak_width_limit(config.min_width_fraction, sigma)
    return peak_minor_on_windows(data, valid, row, col, sigma) < TRACK_PEAK_MARGIN * KEPT_BLEND_TRACK_FRACTION * limit


def ring_track_peaks(frame: CandidateFrame, search: PeakSearch, found: FoundPeaks) -> FoundPeaks:
    """
    Add a cosmic-ray track merged with a ring star to two_peaks' finds (window pixels).

    Ring stars' peaks are searched RING_BLEND_SIGMAS apart from the brightest (the ring's own
    maxima lie up to ~2.7 sigma apart), but a track just outside the ring lies nearer than that
    to the ring's brightest maximum when that is on the track's side. Where no pair was found:
    the brightest maximum at least RING_TRACK_SIGMAS from the spot's centre of light (the
    ring's maxima lie ~1.35 sigma from its centre, the track's light pulls the centre a little),
    with a dip between it and the brightest (two_peaks), counts when it is a track: its own
    pixels' narrowest second moment (peak_shape) under RING_BLEND_TRACK_FRACTION x the width
    limit at an SNR >= shape_min_snr, the brightest peak a star (at least the limit).
    """
    config, sigma = frame.config, frame.sigma
    box, maxima, threshold = search.box, search.maxima, search.threshold
    limit = peak_width_limit(config.min_width_fraction, sigma)
    found, rows, cols = found.found.copy(), found.rows.copy(), found.cols.copy()
    n, height, width = box.shape
    grid_r, grid_c = np.mgrid[0:height, 0:width]
    for k in np.flatnonzero(~found):
        bright = maxima[k] & (box[k] > threshold)
        light = np.maximum(box[k], 0.0)
        total = light.sum()
        if not bright.any() or total <= 0:
            continue
        centre_r, centre_c = (light * grid_r).sum() / total, (light * grid_c).sum() / total
        far = bright & (np.hypot(grid_r - centre_r, grid_c - centre_c) >= RING_TRACK_SIGMAS * sigma)
        if not far.any():
            continue
        first = int(np.argmax(np.where(bright, box[k], -np.inf)))
        second = int(np.argmax(np.where(far, box[k], -np.inf)))
        pair = _pair(frame, search, k, first, second)
        if pair is None:
            continue
        pair_rows, pair_cols, shapes = pair
        if shapes.minor[0] >= limit and shapes.snr[1] >= config.shape_min_snr \
                and shapes.minor[1] < RING_BLEND_TRACK_FRACTION * limit:
            found[k], rows[k], cols[k] = True, pair_rows, pair_cols
    return FoundPeaks(found, rows, cols)


def peak_minor_on_windows(data: np.ndarray, valid: np.ndarray, row: np.ndarray, col: np.ndarray,
                          sigma: float) -> np.ndarray:
    """
    Narrowest second moment [px^2] of each window's pixels (n, R, C) within peak_shape's disk of its pixel (row, col).

    measure.aperture_moments (signed, as peak_shape weighs) over the disk, all windows at once, on the
    cleaned window data (peak_shape measures the raw image less the background at the peak: a
    screen, not its replacement). No positive light: NaN.
    """
    n, height, width = data.shape
    if n == 0:
        return np.zeros(0)
    radius = max(MIN_PEAK_RADIUS_PX, PEAK_RADIUS_SIGMAS * sigma)
    grid_r, grid_c = np.mgrid[0:height, 0:width]
    disk = (grid_r[None] - row[:, None, None]) ** 2 + (grid_c[None] - col[:, None, None]) ** 2 <= radius * radius
    zero = np.zeros(n)
    return aperture_moments(data, disk & valid, zero, zero, 1.0, 1.0, signed_shape=True).minor


def star_beside_track_peaks(frame: CandidateFrame, search: PeakSearch, found: FoundPeaks,
                            thin: np.ndarray) -> FoundPeaks:
    """
    Find the star beside a cosmic-ray track that holds a footprint's brightest maxima (window pixels).

    A track brighter per pixel than the star beside it holds the footprint's brightest maximum,
    and the second two_peaks found (a rasterised track has dips along it) or none: the footprint
    reads thinner than a star (`thin`, the width test's). Where its peaks found (or the brightest
    alone) are all tracks (peak_shape: under KEPT_BLEND_TRACK_FRACTION x the width limit; a star
    measured at too wide a prior reads 0.5-1x), the brightest maximum at least
    blend_separation_px from them whose own pixels are a star's (narrowest second moment at
    least the width limit, SNR >= shape_min_snr), with a dip between it and the first, becomes
    the second peak (of the STAR_SEARCH_MAXIMA brightest such maxima).
    """
    config, sigma = frame.config, frame.sigma
    box, maxima, threshold, col0, row0 = search.box, search.maxima, search.threshold, search.col0, search.row0
    limit = peak_width_limit(config.min_width_fraction, sigma)
    separation = blend_separation_px(sigma, frame.rings)
    found, rows, cols = found.found.copy(), found.rows.copy(), found.cols.copy()
    n, height, width = box.shape
    grid_r, grid_c = np.mgrid[0:height, 0:width]
    for k in np.flatnonzero(thin):
        taken = slice(None) if found[k] else slice(0, 1)
        peaks = np.column_stack([cols[k][taken] + col0[k], rows[k][taken] + row0[k]]).astype(float)
        if not np.isfinite(box[k, rows[k][0], cols[k][0]]) or box[k, rows[k][0], cols[k][0]] <= threshold:
            continue  # no maximum above the threshold: nothing was found
        shapes = peak_minor_moments(frame.image, frame.det, peaks, sigma, config.gain_e_per_adu, centres=False)
        if (shapes.minor >= KEPT_BLEND_TRACK_FRACTION * limit).any():
            continue  # not every peak a track
        apart = np.min(np.hypot(grid_r[None] - rows[k][taken, None, None], grid_c[None] - cols[k][taken, None, None]),
                       axis=0)
        others = np.flatnonzero((maxima[k] & (box[k] > threshold) & (apart >= separation)).ravel())
        first = rows[k][0] * width + cols[k][0]
        for other in others[np.argsort(-box[k].ravel()[others], kind="stable")][:STAR_SEARCH_MAXIMA]:
            pair = _pair(frame, search, k, first, int(other))
            if pair is None:
                continue
            pair_rows, pair_cols, shapes = pair
            if shapes.minor[1] >= limit and shapes.snr[1] >= config.shape_min_snr:
                found[k], rows[k], cols[k] = True, pair_rows, pair_cols
                break
    return FoundPeaks(found, rows, cols)


def _pair(frame: CandidateFrame, search: PeakSearch, k: int, first: int, other: int):
    """
    Window k's maxima `first` and `other` (flat indices) as a pair of peaks, or None without a dip between them.

    Returns their rows and columns (window pixels, the brighter first: two_peaks) and each
    peak's own pixels' PeakShapes (peak_shape, no centres).
    """
    pair = np.zeros((1,) + search.box.shape[1:], bool)
    pair.flat[first] = pair.flat[other] = True
    ok, rows, cols = two_peaks(search.box[k:k + 1], search.box_var[k:k + 1], pair, search.threshold, 0.0)
    if not ok[0]:
        return None
    peaks = np.column_stack([cols[0] + search.col0[k], rows[0] + search.row0[k]]).astype(float)
    return rows[0], cols[0], peak_minor_moments(frame.image, frame.det, peaks, frame.sigma,
                                                frame.config.gain_e_per_adu, centres=False)
