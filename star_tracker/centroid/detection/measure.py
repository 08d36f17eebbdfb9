# SPDX-License-Identifier: Apache-2.0
"""
Per-spot measurements on small windows.

Hot-pixel cleaning, centre of gravity (plain or intensity-weighted) with its noise-model
covariance, shape moments, blend peaks.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import erf

from .hot_pixel_kernel import hot_pixel_hits, replace_hits


def star_peak_to_neighbour_ratio(psf_sigma_px: float) -> float:
    """
    Largest ratio of a star's brightest pixel to its brightest 4-neighbour (star centred on a pixel).

    P0 / P1 with P0, P1 the PSF fractions of the central and next pixel along an axis.
    """
    s = np.sqrt(2.0) * max(psf_sigma_px, 1e-3)
    p0 = erf(0.5 / s)
    p1 = 0.5 * (erf(1.5 / s) - erf(0.5 / s))
    return float(p0 / max(p1, 1e-12))


@functools.lru_cache(maxsize=32)
def cog_phase_bias_rms(psf_sigma_px: float, radius_px: float, power: int = 1) -> float:
    """
    Return the RMS [px per axis] of the centre-of-gravity bias of a noiseless Gaussian PSF.

    A pixel-integrated Gaussian PSF (1-sigma psf_sigma_px [px]) measured in a circular
    aperture of radius radius_px [px] centred on the pixel nearest to the star, over the
    star's sub-pixel phase (uniform). power 1: plain centre of gravity; 2:
    intensity-weighted (weights r^2). The aperture cuts the PSF's wings unevenly unless the
    star sits on a pixel centre: a bias of up to a few hundredths of a pixel that no noise
    term contains (0.021 px for a 1 px PSF, the measured excess error of bright centres of
    gravity in the simulator).
    """
    sigma = max(psf_sigma_px, 1e-3)
    reach = int(np.ceil(radius_px)) + 1
    k = np.arange(-reach, reach + 1, dtype=float)
    inside = np.hypot(k[:, None], k[None, :]) <= radius_px
    phases = (np.arange(24) + 0.5) / 24 - 0.5
    bias = []
    for dy in phases[::2]:
        py = 0.5 * (erf((k + 0.5 - dy) / (np.sqrt(2.0) * sigma)) - erf((k - 0.5 - dy) / (np.sqrt(2.0) * sigma)))
        for dx in phases:
            px = 0.5 * (erf((k + 0.5 - dx) / (np.sqrt(2.0) * sigma)) - erf((k - 0.5 - dx) / (np.sqrt(2.0) * sigma)))
            weight = (np.outer(py, px) ** power) * inside
            bias.append(np.sum(weight * k[None, :]) / np.sum(weight) - dx)
    return float(np.sqrt(np.mean(np.square(bias))))


def clean_hot_pixels(windows: np.ndarray, valid: np.ndarray, noise: float, ratio_limit: float):
    """
    Replace isolated hot pixels / cosmic-ray hits in background-subtracted windows (n, S, S) [ADU].

    Each is replaced by the mean of its 4 neighbours: a pixel brighter than ratio_limit x its
    brightest neighbour + 5 noise sigmas cannot come from a PSF that wide. Neighbours outside
    `valid` read 0; a window's first and last rows are not tested. Returns (cleaned, hit mask);
    cleaned is `windows` itself when nothing was hit (compiled: hot_pixel_kernel.py).
    """
    if not np.isfinite(ratio_limit):
        return windows, np.zeros(windows.shape, bool)
    stack = np.ascontiguousarray(windows if windows.dtype in (np.float32, np.float64) else windows.astype(float))
    valid = np.ascontiguousarray(valid, np.bool_)
    all_valid = bool(valid.all())
    hit, count = hot_pixel_hits(stack, valid, all_valid, float(noise), float(ratio_limit))
    if count == 0:
        return windows, hit
    cleaned = stack.copy()
    replace_hits(stack, valid, all_valid, hit, cleaned)
    return cleaned, hit


@dataclass(frozen=True)
class Moments:
    """
    Aperture measurements (n spots).

    Flux [ADU], centre of gravity x, y [px], its covariance cov (n, 2, 2) [px^2], snr, second
    moments mxx, myy, mxy of the positive signal [px^2], minor/major principal moments [px^2],
    peak (brightest pixel) [ADU].
    """

    flux: np.ndarray
    x: np.ndarray
    y: np.ndarray
    cov: np.ndarray
    snr: np.ndarray
    minor: np.ndarray
    major: np.ndarray
    angle: np.ndarray
    peak: np.ndarray


@functools.lru_cache(maxsize=64)
def _moment_features(size_r: int, size_c: int) -> np.ndarray:
    """(P, 6) per-pixel 1, x, y, x^2, y^2, xy of an R x C window (local coordinates)."""
    lr, lc = np.mgrid[0:size_r, 0:size_c]
    lc, lr = lc.ravel().astype(float), lr.ravel().astype(float)
    return np.stack([np.ones_like(lc), lc, lr, lc * lc, lr * lr, lc * lr], axis=1)


def aperture_moments(windows: np.ndarray, use: np.ndarray, col0: np.ndarray, row0: np.ndarray, noise: float,
                     gain: float, power: int = 1, signed_shape: bool = False) -> Moments:
    """
    Return the centre of gravity of the pixels in `use` (n, R, C) of background-subtracted windows.

    The windows' top-left pixel is (col0, row0) [px].

    power 1: plain centre of gravity, weights r_i; power 2: intensity-weighted, weights
    max(r_i, 0)^2 (less noise from the faint wings, more pixel-phase bias). The covariance
    propagates the per-pixel variance var_i = max(r_i, 0)/gain + noise^2 through the weights.
    Second moments weight the positive signal, or with signed_shape the signed one (noise
    cancels on average instead of widening every spot; noisier, NaN when the sum is <= 0).
    """
    n, size_r, size_c = windows.shape
    features = _moment_features(size_r, size_c)
    r = np.where(use, windows, 0.0).reshape(n, -1)
    positive = np.maximum(r, 0.0)
    var = np.where(use.reshape(n, -1), positive / gain + noise * noise, 0.0)
    if power == 1:
        weight, dweight = r, use.reshape(n, -1).astype(float)
    else:
        weight, dweight = positive * positive, 2.0 * positive
    sw, sv, sp = weight @ features, (var * dweight * dweight) @ features, (r if signed_shape else positive) @ features
    if signed_shape:
        sp[sp[:, 0] <= 0] = np.nan
    flux = r.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = flux / np.sqrt(var.sum(axis=1))
        cx, cy = sw[:, 1] / sw[:, 0], sw[:, 2] / sw[:, 0]
        # d cx / d r_i = dweight_i (x_i - cx) / total; sums of var dw^2 (x_i - cx)(y_i - cy) expanded.
        t2 = sw[:, 0] ** 2
        cov = np.empty((n, 2, 2))
        cov[:, 0, 0] = (sv[:, 3] - 2 * cx * sv[:, 1] + cx * cx * sv[:, 0]) / t2
        cov[:, 1, 1] = (sv[:, 4] - 2 * cy * sv[:, 2] + cy * cy * sv[:, 0]) / t2
        cov[:, 0, 1] = cov[:, 1, 0] = (sv[:, 5] - cx * sv[:, 2] - cy * sv[:, 1] + cx * cy * sv[:, 0]) / t2
        # Shape from the positive signal around its own centre.
        px, py = sp[:, 1] / sp[:, 0], sp[:, 2] / sp[:, 0]
        mxx = sp[:, 3] / sp[:, 0] - px * px
        myy = sp[:, 4] / sp[:, 0] - py * py
        mxy = sp[:, 5] / sp[:, 0] - px * py
    spread = np.sqrt(0.25 * (mxx - myy) ** 2 + mxy ** 2)
    angle = 0.5 * np.arctan2(2.0 * mxy, mxx - myy)
    peak = np.where(use.reshape(n, -1), r, -np.inf).max(axis=1)
    return Moments(flux=flux, x=cx + np.asarray(col0, float), y=cy + np.asarray(row0, float), cov=cov, snr=snr,
                   minor=0.5 * (mxx + myy) - spread, major=0.5 * (mxx + myy) + spread, angle=angle, peak=peak)


def major_moment_noise(windows: np.ndarray, use: np.ndarray, col0: np.ndarray, row0: np.ndarray, moments: Moments,
                       noise: float, gain: float) -> np.ndarray:
    """
    Return the 1-sigma noise [px^2] of each spot's signed second moment along its major axis.

    `moments`: aperture_moments(windows, use, col0, row0, noise, gain, signed_shape=True).
    The moment M = sum r_i u_i^2 / sum r_i (u_i along the major axis from the centre) moves by
    (u_i^2 - M) / flux per unit of pixel i, whose variance is max(r_i, 0)/gain + noise^2.
    """
    n, size_r, size_c = windows.shape
    rows, cols = np.mgrid[0:size_r, 0:size_c]
    dx = cols[None] - (moments.x - np.asarray(col0, float))[:, None, None]
    dy = rows[None] - (moments.y - np.asarray(row0, float))[:, None, None]
    along = dx * np.cos(moments.angle)[:, None, None] + dy * np.sin(moments.angle)[:, None, None]
    signal = np.where(use, windows, 0.0)
    var = np.where(use, np.maximum(signal, 0.0) / gain + noise * noise, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = (along * along - moments.major[:, None, None]) / moments.flux[:, None, None]
        return np.sqrt((var * slope * slope).sum(axis=(1, 2)))


def secondary_peaks(windows: np.ndarray, valid: np.ndarray, centre: int, threshold: float, min_separation: float,
                    radius: float, gain: float, noise: float):
    """
    Return the brightest separate local maximum of the 3x3 box sum (box_sums) of each window (n, S, S).

    It is at least `min_separation` px from the window centre, within `radius` px of it, above
    `threshold` [ADU, box sum] and separated from the central peak by a dip (the box sum
    half-way between them is below 0.9x the fainter peak). Returns (found (n,), row, col).
    """
    n, size, _ = windows.shape
    box, _, maxima = box_sums(windows, valid, gain, noise)
    rr, cc = np.mgrid[0:size, 0:size]
    dist = np.hypot(rr - centre, cc - centre)
    candidate = maxima & (box > threshold) & (dist >= min_separation) & (dist <= radius)
    score = np.where(candidate, box, -np.inf).reshape(n, -1)
    best = score.argmax(axis=1)
    found = np.isfinite(score[np.arange(n), best])
    row, col = best // size, best % size
    mid_r = np.rint(0.5 * (row + centre)).astype(int)
    mid_c = np.rint(0.5 * (col + centre)).astype(int)
    idx = np.arange(n)
    dip = box[idx, mid_r, mid_c] < 0.9 * np.minimum(box[idx, row, col], box[idx, centre, centre])
    return found & dip, row, col


def box_sums(windows: np.ndarray, use: np.ndarray, gain: float, noise: float):
    """
    3x3 box sums of windows (n, R, C) [ADU] inside `use`.

    Their variance (shot + pixel noise) and a mask of their local maxima. Windows are
    processed stacked (one OpenCV call); a window's first and last rows are never maxima
    (they see the neighbouring window).
    """
    n, rows, cols = windows.shape
    signal = np.where(use, windows, 0.0).astype(np.float32).reshape(n * rows, cols)
    box = cv2.boxFilter(signal, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    box_var = cv2.boxFilter(np.maximum(signal, 0.0) / gain, -1, (3, 3), normalize=False,
                            borderType=cv2.BORDER_CONSTANT) + 9.0 * noise * noise
    ring = np.ones((3, 3), np.uint8)
    ring[1, 1] = 0
    neighbours = cv2.dilate(box, ring, borderType=cv2.BORDER_CONSTANT, borderValue=-np.inf)
    maxima = (box > neighbours).reshape(n, rows, cols) & use
    maxima[:, 0, :] = maxima[:, -1, :] = False
    return box.reshape(n, rows, cols), box_var.reshape(n, rows, cols), maxima


def two_peaks(box: np.ndarray, box_var: np.ndarray, maxima: np.ndarray, threshold: float,
              min_separation: float):
    """
    Return the two brightest separate peaks of each window, from its box sums (see box_sums).

    Local maxima above `threshold` [ADU, box sum], at least `min_separation` px apart, with a
    real dip between them: the box sum's minimum on the segment joining them is below 0.8x the
    fainter peak and more than 5 sigma (its shot + pixel noise) under it -- two stars, not noise
    bumps on one smooth spot or along a streak. Returns (found (n,), rows (n, 2), cols (n, 2)) in
    window pixels, brightest first; all windows at once.
    """
    n, rows, cols = box.shape
    score = np.where(maxima & (box > threshold), box, -np.inf).reshape(n, -1)
    first = score.argmax(axis=1)
    r1, c1 = first // cols, first % cols
    rr, cc = np.mgrid[0:rows, 0:cols]
    far = (np.hypot(rr[None] - r1[:, None, None], cc[None] - c1[:, None, None]) >= min_separation).reshape(n, -1)
    idx = np.arange(n)
    t = np.linspace(0.0, 1.0, 17)
    found = np.zeros(n, bool)
    r2, c2 = r1.copy(), c1.copy()
    candidates = np.where(far & np.isfinite(score[idx, first])[:, None], score, -np.inf)
    for _ in range(3):  # the three brightest other maxima, brightest passing first
        second = candidates.argmax(axis=1)
        exists = np.isfinite(candidates[idx, second]) & ~found
        cr, ccol = second // cols, second % cols
        lr = np.rint(r1[:, None] + t[None] * (cr - r1)[:, None]).astype(int)
        lc = np.rint(c1[:, None] + t[None] * (ccol - c1)[:, None]).astype(int)
        low = box[idx[:, None], lr, lc].min(axis=1)
        fainter = np.minimum(box[idx, r1, c1], box[idx, cr, ccol])
        dip = fainter - low
        ok = exists & (dip > 0.2 * fainter) & (dip > 5.0 * np.sqrt(2.0 * box_var[idx, cr, ccol]))
        r2, c2 = np.where(ok, cr, r2), np.where(ok, ccol, c2)
        found |= ok
        candidates[idx, second] = -np.inf
    return found, np.column_stack([r1, r2]), np.column_stack([c1, c2])
