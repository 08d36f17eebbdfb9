# SPDX-License-Identifier: Apache-2.0
"""
The PSF width of a rate-aided frame, measured across its streaks.

Under a known body rate no star shows the optics' round PSF, but a streak's profile across its
track is that PSF's (a Gaussian of 1-sigma s, broadened by the pixels to s^2 + 1/12 px^2 in
any direction). Without this a camera whose PSF differs from the prior, in motion from its
first aided frame (a gyro aid, a defocus in orbit), was measured at the prior's width for good:
at 2.5 px against the default 1 px, a slew's spots were ~7x more uncertain than they stated.

For the brightest streaks (SNR >= MIN_SNR, windows inside the image, length >= MIN_LENGTH_PX): the pixels
of a window around the streak are placed in track coordinates (along, across) from the smear
model's direction; those within the track's length are binned across it (BIN_PX), each bin's
mean less a local background (the window's outer ring's median), and ln(profile) fitted by a
parabola over the bins above PROFILE_FLOOR of the peak (a Gaussian's log is one): s^2 = -1/(2
curvature) - 1/12; a profile whose peak lies more than MAX_VERTEX_OFFSET of that width from the
streak's centre of light, or whose core (above CORE_FLOOR) gives a width more than
MAX_CORE_MISMATCH from it, is two stars merged across the track and left out. The frame's width
is the median over at least MIN_STREAKS streaks. When most profiles read narrower than
narrow_width.NARROW_PX (or too narrow for the parabola), the PSF is undersampled and each
streak's width is fitted on its pixels with their integral instead (narrow_width.py). A field
whose brightest streaks mostly have a companion 2-3 sigma across their track, merged into one
detection and not caught by those tests, reads wider than its PSF (test_centroid_scenes' field
of pairs: 1.7 px for 1 px).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .model import PIXEL_VARIANCE
from .narrow_width import NARROW_PX, narrow_width

if TYPE_CHECKING:
    from .smear import SmearModel

MIN_SNR = 15.0
MIN_LENGTH_PX = 3.0
MAX_STREAKS = 8
MIN_STREAKS = 3
# Measured again at their own width, this many streaks whose widths agree within AGREEMENT
# (relative) give the frame's: psf_loop._after_few_streaks.
MIN_AGREEING_STREAKS = 2
AGREEMENT = 0.1
BIN_PX = 0.5
PROFILE_FLOOR = 0.15  # fraction of the profile's peak the log-parabola fit keeps
CORE_FLOOR = 0.5  # the core's fit, compared with the whole profile's
MAX_CORE_MISMATCH = 0.12  # relative difference of the core's width from the profile's beyond which it is a blend
MAX_ACROSS_PX = 12.0  # the widest profile looked at: 4 x the 3 px PSF
MAX_VERTEX_OFFSET = 0.25  # the profile's peak this far (in its own sigmas) from the streak's centre: a blend
_UNPROFILED, _NARROW, _WIDE = "unprofiled", "narrow", "wide"  # a streak's profile: none; below NARROW_PX; wider


def streak_width(image: np.ndarray, x: np.ndarray, y: np.ndarray, snr: np.ndarray, smear: "SmearModel"
                 ) -> tuple[float, float, int]:
    """
    Return (sigma_px, its 1-sigma uncertainty, streaks used) across the frame's streaks, or (nan, nan, n).

    image [ADU]; x, y [px], snr [-]: the frame's measured spots (candidates); smear: the aid's model.
    """
    return frame_width(streak_widths(image, x, y, snr, smear))


def streak_widths(image: np.ndarray, x: np.ndarray, y: np.ndarray, snr: np.ndarray, smear: "SmearModel"
                  ) -> np.ndarray:
    """Return the PSF widths [px] across the brightest streaks (up to MAX_STREAKS; arguments as streak_width)."""
    x, y = (np.asarray(v, float).ravel() for v in (x, y))
    finite = np.isfinite(x) & np.isfinite(y)
    vectors = np.full((x.size, 2), np.nan)
    spread = None
    if finite.any():
        vectors[finite] = smear.smear_vectors(x[finite], y[finite])
        if smear.exposure_path is not None:  # only for the streaks bright enough to be measured
            spread = np.zeros(x.size)
            bright = finite & (np.asarray(snr, float).ravel() >= MIN_SNR)
            if bright.any():
                spread[bright] = path_variance_across(smear.path(x[bright], y[bright]), vectors[bright])
    return streak_widths_along(image, x, y, snr, vectors, path_variance_px2=spread)


def path_variance_across(path: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """
    Return the variance [px^2] across each streak's chord of its path's samples (N,).

    path (N, K, 2) [px], vectors (N, 2) end minus start [px]: a gyro-measured path (jitter)
    sways across its chord, which widens the profile across the track by this variance.
    """
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    unit = np.divide(vectors, length, out=np.zeros_like(vectors), where=length > 0)
    across = path[:, :, 0] * -unit[:, None, 1] + path[:, :, 1] * unit[:, None, 0]
    return np.nan_to_num(np.var(across, axis=1))


def streak_widths_along(image: np.ndarray, x: np.ndarray, y: np.ndarray, snr: np.ndarray, vectors: np.ndarray,
                        turns_rad: tuple[float, ...] = (0.0,), path_variance_px2: np.ndarray | None = None
                        ) -> np.ndarray:
    """
    Return the PSF widths [px] across the brightest streaks, each along its own smear vector.

    vectors (N, 2): end minus start of each streak [px] (a smear model's, or a streak's own
    direction and length when the rate is unknown); turns_rad: each streak is measured along
    its vector turned by each of these angles [rad] and the narrowest profile kept (the track's
    own direction when the vector's is only approximate: a profile across a track at an angle
    is wider by the track's length times the angle's sine); path_variance_px2 (N,): the
    variance across the track its known path adds (path_variance_across), taken off each
    profile's; the rest as streak_width.
    """
    x, y, snr = (np.asarray(v, float).ravel() for v in (x, y, snr))
    vectors = np.asarray(vectors, float).reshape(-1, 2)
    index = np.flatnonzero(np.isfinite(snr) & (snr >= MIN_SNR) & np.isfinite(x) & np.isfinite(y))
    index = index[np.argsort(-snr[index])]
    widths, narrow, profiled = _widths(image, x, y, vectors, index, turns_rad, path_variance_px2, False)
    # Most profiles narrower than NARROW_PX (or too narrow to fit): an undersampled PSF, each
    # streak fitted again with the pixels' integral (narrow_width). A few narrow ones among
    # wider (a hot pixel on a track) keep their reading.
    if narrow > 0.5 * profiled:
        widths, _, _ = _widths(image, x, y, vectors, index, turns_rad, path_variance_px2, True)
    return widths


def _widths(image: np.ndarray, x, y, vectors, index, turns_rad, path_variance_px2, refit_narrow: bool
            ) -> tuple[np.ndarray, int, int]:
    """Return (widths [px] of streaks `index`, up to MAX_STREAKS; profiles read narrow; streaks profiled)."""
    height, width = image.shape
    widths, narrow, profiled = [], 0, 0
    for i in index:
        if len(widths) >= MAX_STREAKS:
            break
        across = [_one_streak(image, float(x[i]), float(y[i]), _turned(vectors[i], turn), width, height, refit_narrow)
                  for turn in turns_rad]
        profiled += any(shape != _UNPROFILED for _, shape in across)
        narrow += any(shape == _NARROW for _, shape in across)
        sigma = min((value for value, _ in across if np.isfinite(value)), default=float("nan"))
        if path_variance_px2 is not None and np.isfinite(sigma):
            variance = sigma * sigma - float(path_variance_px2[i])
            sigma = float(np.sqrt(variance)) if variance > 0 else float("nan")
        if np.isfinite(sigma):
            widths.append(sigma)
    return np.asarray(widths, float), narrow, profiled


def frame_width(widths: np.ndarray, min_streaks: int = MIN_STREAKS) -> tuple[float, float, int]:
    """Return (median [px], its 1-sigma uncertainty, count) of streak widths; (nan, nan, count) below min_streaks."""
    values = np.asarray(widths, float)
    if values.size < min_streaks:
        return float("nan"), float("nan"), int(values.size)
    median = float(np.median(values))
    spread = 1.4826 * float(np.median(np.abs(values - median)))
    return median, 1.2533 * spread / np.sqrt(values.size), int(values.size)


def _turned(vector: np.ndarray, angle: float) -> np.ndarray:
    """Return `vector` (2,) turned by `angle` [rad]."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([c * vector[0] - s * vector[1], s * vector[0] + c * vector[1]])


def _one_streak(image: np.ndarray, x: float, y: float, vector: np.ndarray, width: int, height: int,
                refit_narrow: bool = False) -> tuple[float, str]:
    """
    Return (the PSF width [px] across one streak or NaN, its profile's shape: _UNPROFILED, _NARROW or _WIDE).

    refit_narrow: a narrow profile's width is fitted with the pixels' integral (narrow_width).
    """
    nothing = (float("nan"), _UNPROFILED)
    length = float(np.hypot(*vector))
    if not np.isfinite(length) or length < MIN_LENGTH_PX:
        return nothing
    along_unit = vector / length
    across_unit = np.array([-along_unit[1], along_unit[0]])
    half = int(np.ceil(0.5 * length + MAX_ACROSS_PX))
    col0, row0 = int(round(x)) - half, int(round(y)) - half
    if col0 < 0 or row0 < 0 or col0 + 2 * half + 1 > width or row0 + 2 * half + 1 > height:
        return nothing
    window = image[row0:row0 + 2 * half + 1, col0:col0 + 2 * half + 1].astype(float)
    rows, cols = np.mgrid[row0:row0 + 2 * half + 1, col0:col0 + 2 * half + 1]
    dx, dy = cols - x, rows - y
    along = dx * along_unit[0] + dy * along_unit[1]
    across = dx * across_unit[0] + dy * across_unit[1]
    on_track = np.abs(along) <= 0.5 * length
    outer = on_track & (np.abs(across) > 0.75 * MAX_ACROSS_PX)
    if np.count_nonzero(outer) < 8:
        return nothing
    background = float(np.median(window[outer]))
    inside = on_track & (np.abs(across) <= MAX_ACROSS_PX)
    bins = np.floor(across[inside] / BIN_PX).astype(int)
    bins -= bins.min()
    counts = np.bincount(bins)
    sums = np.bincount(bins, weights=window[inside] - background)
    filled = counts > 0
    centres = (np.flatnonzero(filled) + 0.5) * BIN_PX + np.floor(across[inside].min() / BIN_PX) * BIN_PX
    profile = sums[filled] / counts[filled]
    peak = profile.max()
    if not peak > 0:
        return nothing
    wide = _log_parabola(centres, profile, PROFILE_FLOOR)
    shape = _NARROW if _narrow_profile(centres, profile, wide) else _WIDE
    if shape == _NARROW and refit_narrow:
        # A PSF narrower than the pixel: its few bins' shape is the pixel's as much as the PSF's.
        narrow = narrow_width((window - background).ravel(), along.ravel(), across.ravel(), along_unit, length,
                              math.sqrt(wide[0]) if wide is not None else float("nan"))
        if narrow is not None:
            sigma, offset = narrow
            # Off the streak's centre of light across the track: two stars merged (as below).
            merged = abs(offset) > MAX_VERTEX_OFFSET * math.sqrt(sigma * sigma + PIXEL_VARIANCE)
            return (float("nan") if merged else sigma), shape
    if wide is None:
        return float("nan"), shape
    variance, vertex = wide
    # A single star's profile peaks on its centre of light, and its core and its wings give the
    # same width; two stars merged across the track (one detection) peak off that centre, or
    # make a core flatter than the wings: not one PSF's profile.
    if abs(vertex) > MAX_VERTEX_OFFSET * np.sqrt(variance):
        return float("nan"), shape
    core = _log_parabola(centres, profile, CORE_FLOOR)
    if core is not None and abs(np.sqrt(core[0] / variance) - 1.0) > MAX_CORE_MISMATCH:
        return float("nan"), shape
    return float(np.sqrt(variance)), shape


def _narrow_profile(centres: np.ndarray, profile: np.ndarray, wide: tuple[float, float] | None) -> bool:
    """Whether a profile reads narrower than NARROW_PX: its log-parabola's width, or too few bins above the floor."""
    if wide is not None:
        return wide[0] < NARROW_PX * NARROW_PX
    above = profile > PROFILE_FLOOR * profile.max()
    return int(np.count_nonzero(above)) < 4 or _log_parabola_variance(centres, profile) <= 0.0


def _log_parabola_variance(centres: np.ndarray, profile: np.ndarray) -> float:
    """Return the log-parabola's PSF variance [px^2] over the bins above the floor (any sign; NaN: not concave)."""
    keep = profile > PROFILE_FLOOR * profile.max()
    if np.count_nonzero(keep) < 3:
        return float("nan")
    curvature = np.polyfit(centres[keep], np.log(profile[keep]), 2, w=np.sqrt(profile[keep]))[0]
    return float(-0.5 / curvature - PIXEL_VARIANCE) if curvature < 0 else float("nan")


def _log_parabola(centres: np.ndarray, profile: np.ndarray, floor: float) -> tuple[float, float] | None:
    """Return (variance [px^2], peak offset [px]) of a Gaussian fit to the profile above floor x its peak."""
    keep = profile > floor * profile.max()
    # The profile's core only: the bins above the floor contiguous with the peak.
    top = int(np.argmax(profile))
    left, right = top, top
    while left > 0 and keep[left - 1]:
        left -= 1
    while right < keep.size - 1 and keep[right + 1]:
        right += 1
    if right - left + 1 < 4:
        return None
    c, p = centres[left:right + 1], profile[left:right + 1]
    curvature, slope, _ = np.polyfit(c, np.log(p), 2, w=np.sqrt(p))
    if not curvature < 0:
        return None
    variance = -0.5 / curvature - PIXEL_VARIANCE
    return (float(variance), float(-slope / (2.0 * curvature))) if variance > 0 else None
