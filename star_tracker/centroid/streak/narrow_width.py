# SPDX-License-Identifier: Apache-2.0
"""
The PSF width across a narrow streak, fitted with the pixels' own integral of the streak.

streak_width reads a streak's width off its profile across the track, binned by the pixel
centres' distance from it, as a Gaussian broadened by the pixel (s^2 + 1/12 px^2). That holds
for a PSF of a pixel or wider. An undersampled one (s below NARROW_PX) leaves a profile of a few
bins whose shape is the pixel's square seen at the track's angle as much as the PSF: on the
independent renderer's streaks of a 0.4 px PSF smeared 3 px, the log-parabola read 0.27-0.30 px
for every streak of a frame, below the 0.3 px the fits support, and the frame was measured at
the configured 1 px, where its sharp streaks were all refused as cosmic-ray tracks.

Here the pixels near the streak are fitted directly: each pixel's value is the mean over
SUBPIXELS x SUBPIXELS points of the pixel of a straight streak of the known length and direction
(a segment of uniform light convolved with a round Gaussian of 1-sigma s: along the track the
difference of two normal CDFs, across it a normal density), scaled by a flux, its centre
shifted along and across; s, the shifts and the flux by least squares (scipy's
least_squares). The background is the caller's. Pixel positions [px], (0, 0) the centre of the
top-left pixel.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares
from scipy.special import ndtr

NARROW_PX = 0.7  # a log-parabola width below this (or none) is fitted again here [px]
SUBPIXELS = 7  # points per pixel side of the integral (0.14 px apart: < 0.5 sigma at 0.3 px)
REACH_ACROSS_SIGMAS = 4.0  # pixels this far across (in the first guess's sigmas, at least 1.5 px) are fitted
REACH_ALONG_PX = 2.0  # and this far beyond the track's ends
MIN_SIGMA_PX, MAX_SIGMA_PX = 0.15, 1.5  # the fit's bounds [px]
MIN_PIXELS = 12  # fewer pixels in reach: no fit


def _offsets() -> np.ndarray:
    """Return the sub-pixel points' offsets from a pixel's centre (SUBPIXELS^2, 2) [px]."""
    steps = (np.arange(SUBPIXELS) + 0.5) / SUBPIXELS - 0.5
    dx, dy = np.meshgrid(steps, steps)
    return np.column_stack([dx.ravel(), dy.ravel()])


_SUBPIXEL_OFFSETS = _offsets()


def streak_pixels(along: np.ndarray, across: np.ndarray, unit: np.ndarray, length: float, sigma: float,
                  shift_along: float, shift_across: float) -> np.ndarray:
    """
    Return the unit-flux streak's mean over each pixel (N,).

    along, across (N,) [px]: the pixels' centres in track coordinates from the streak's
    assumed centre; unit (2,): the track's direction in the image (x, y); length [px]; sigma
    [px]: the PSF's 1-sigma; shift_along, shift_across [px]: the streak's centre in those
    coordinates. Per unit flux: along the track the light of a segment blurred by the PSF,
    (Phi((a + L/2) / s) - Phi((a - L/2) / s)) / L, across it the normal density.
    """
    # Sub-pixel points in track coordinates: a pixel's square turned by the track's angle.
    ox, oy = _SUBPIXEL_OFFSETS[:, 0], _SUBPIXEL_OFFSETS[:, 1]
    sub_along = along[:, None] + (ox * unit[0] + oy * unit[1])[None, :] - shift_along
    sub_across = across[:, None] + (-ox * unit[1] + oy * unit[0])[None, :] - shift_across
    half = 0.5 * length
    along_light = (ndtr((sub_along + half) / sigma) - ndtr((sub_along - half) / sigma)) / length
    across_light = np.exp(-0.5 * (sub_across / sigma) ** 2) / (math.sqrt(2.0 * math.pi) * sigma)
    return np.mean(along_light * across_light, axis=1)


def narrow_width(values: np.ndarray, along: np.ndarray, across: np.ndarray, unit: np.ndarray, length: float,
                 guess_px: float) -> tuple[float, float] | None:
    """
    Return (sigma [px], centre's offset across the track [px]) fitted to a streak's pixels, or None.

    values (N,) [ADU, background removed], along, across (N,) [px]: the window's pixels and
    their centres in track coordinates (from the streak's measured centre); unit (2,) the
    track's direction (x, y); length [px] the smear's; guess_px: the first guess of sigma.
    None when too few pixels are in reach, the fit fails or sigma ends on a bound.
    """
    guess = float(np.clip(guess_px if np.isfinite(guess_px) else 0.5, 0.3, 1.0))
    reach = max(REACH_ACROSS_SIGMAS * guess, 1.5)
    near = (np.abs(across) <= reach) & (np.abs(along) <= 0.5 * length + REACH_ALONG_PX)
    if np.count_nonzero(near) < MIN_PIXELS:
        return None
    data, a, c = values[near], along[near], across[near]
    flux0 = max(float(np.sum(data)), 1e-9)

    def residual(p):
        sigma, shift_along, shift_across, flux = p
        return flux * streak_pixels(a, c, unit, length, sigma, shift_along, shift_across) - data

    start = np.array([guess, 0.0, 0.0, flux0])
    lower = np.array([MIN_SIGMA_PX, -1.0, -1.0, 0.0])
    upper = np.array([MAX_SIGMA_PX, 1.0, 1.0, 10.0 * flux0 + 1.0])
    try:
        fit = least_squares(residual, start, bounds=(lower, upper), x_scale=np.array([0.1, 0.1, 0.1, flux0]))
    except (ValueError, np.linalg.LinAlgError):
        return None
    sigma = float(fit.x[0])
    if not fit.success or not np.isfinite(sigma) or sigma <= MIN_SIGMA_PX * 1.01 or sigma >= MAX_SIGMA_PX * 0.99:
        return None
    return sigma, float(fit.x[2])
