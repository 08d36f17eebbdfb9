# SPDX-License-Identifier: Apache-2.0
"""
The point-window measurement of every detection, compiled (numba): candidates.measure_candidates' small spots.

Per detection a search window, hot pixels cleaned, re-centred on its brightest box, and a
circular-aperture measurement (centre of gravity, covariance, second moments, SNR): the work
per spot is too small for numpy's per-call overhead to pay off.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ..kernel_image import WARM_IMAGE_DTYPES, read_only
from .hot_pixel_kernel import is_hot, neighbour_mean


@njit(cache=True)
def _centre_and_covariance(weighted_sums, variance_sums, col0, row0, out_x, out_y, out_cov, s):
    """
    Centre of gravity and its covariance from the weighted and variance sums of a window.

    The centre from sums of w (1, x, y), its covariance from sums of var (dw/dr)^2 (1, x, y,
    x^2, y^2, xy) (local window coordinates; written at index s).
    """
    total = weighted_sums[0]
    if total == 0.0:
        return
    x, y = weighted_sums[1] / total, weighted_sums[2] / total
    v = variance_sums
    t2 = total * total
    out_x[s], out_y[s] = x + col0, y + row0
    out_cov[s, 0, 0] = (v[3] - 2 * x * v[1] + x * x * v[0]) / t2
    out_cov[s, 1, 1] = (v[4] - 2 * y * v[2] + y * y * v[0]) / t2
    out_cov[s, 0, 1] = out_cov[s, 1, 0] = (v[5] - x * v[2] - y * v[1] + x * y * v[0]) / t2


class SmallSpots(NamedTuple):
    """
    Detections to measure in a point window, per spot (n,).

    cx, cy the footprint centroid [px]; bg the background there [ADU] and bg_dx, bg_dy its
    slopes [ADU/px] (detect.BackgroundPlane: the windows subtract the plane); top, bottom, left,
    right its bounding box (full-resolution px, bottom/right exclusive; int64).
    """

    cx: np.ndarray
    cy: np.ndarray
    bg: np.ndarray
    bg_dx: np.ndarray
    bg_dy: np.ndarray
    top: np.ndarray
    bottom: np.ndarray
    left: np.ndarray
    right: np.ndarray


class PointWindowSettings(NamedTuple):
    """
    How measure_small measures.

    half (int) the half size of the measuring window [px]; search_margin (int) the search
    window's extra size [px]; sigma the PSF 1-sigma [px]; noise the pixel noise [ADU]; gain
    [e-/ADU]; ratio_limit the hot-pixel peak-to-neighbour ratio (inf: no cleaning);
    weighted: also the intensity-weighted centre of gravity.
    """

    half: int
    search_margin: int
    sigma: float
    noise: float
    gain: float
    ratio_limit: float
    weighted: bool


class SmallSpotMeasurements(NamedTuple):
    """
    measure_small's results per spot (n,).

    x, y [px], flux [ADU], snr, minor, major [px^2], angle [rad], peak, peak_raw [ADU], cov
    (n, 2, 2) [px^2], wx, wy, wcov (intensity-weighted centre), edge, cleaned; window,
    window_valid (n, S, S) and their top-left pixel window_col0, window_row0; search,
    search_valid (n, B, B): the cleaned search windows and their top-left pixel search_col0,
    search_row0.
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    snr: np.ndarray
    minor: np.ndarray
    major: np.ndarray
    angle: np.ndarray
    peak: np.ndarray
    peak_raw: np.ndarray
    cov: np.ndarray
    wx: np.ndarray
    wy: np.ndarray
    wcov: np.ndarray
    edge: np.ndarray
    cleaned: np.ndarray
    window: np.ndarray
    window_valid: np.ndarray
    window_col0: np.ndarray
    window_row0: np.ndarray
    search: np.ndarray
    search_valid: np.ndarray
    search_col0: np.ndarray
    search_row0: np.ndarray


def measure_small(image: np.ndarray, spots: SmallSpots, settings: PointWindowSettings) -> SmallSpotMeasurements:
    """Point-window measurements of the detections `spots` (_measure_small, compiled)."""
    return SmallSpotMeasurements(*_measure_small(read_only(image), spots, settings))


@njit(cache=True)
def _clean_search_window(image, c0, r0, plane, ratio_limit, noise, raw, win, valid):
    """
    Fill the search window (top-left pixel (c0, r0)) from `image` less the background plane, hot pixels cleaned.

    plane: (level [ADU] at (x, y), x, y [px], slope_x, slope_y [ADU/px]).

    raw, win, valid (big, big) are overwritten (raw: the image's values, a hot pixel's replaced by
    its cleaned value plus the background); returns whether a hot pixel was cleaned. The
    4-neighbour test of measure.clean_hot_pixels (hot_pixel_kernel.is_hot, neighbour_mean):
    interior rows only (as the stacked OpenCV pass), replicate at the columns.
    """
    height, width = image.shape
    big = win.shape[0]
    level, px, py, slope_x, slope_y = plane
    for i in range(big):
        for j in range(big):
            rr, cc = r0 + i, c0 + j
            inside = 0 <= rr < height and 0 <= cc < width
            valid[i, j] = inside
            raw[i, j] = float(image[min(max(rr, 0), height - 1), min(max(cc, 0), width - 1)]) if inside else 0.0
            win[i, j] = raw[i, j] - (level + slope_x * (cc - px) + slope_y * (rr - py)) if inside else 0.0
    hit_any = False
    cleaned = win.copy()
    ratio, floor = np.float32(ratio_limit), np.float32(5.0 * noise)
    for i in range(1, big - 1):
        for j in range(big):
            if not valid[i, j]:
                continue
            up = np.float32(win[i - 1, j])
            down = np.float32(win[i + 1, j])
            left = np.float32(win[i, j - 1] if j > 0 else win[i, j])
            right = np.float32(win[i, j + 1] if j < big - 1 else win[i, j])
            if is_hot(win[i, j], up, left, right, down, ratio, floor):
                hit_any = True
                cleaned[i, j] = float(neighbour_mean(up, left, right, down))
                # The raw value too: a hot pixel's reading is no star's peak (it would outrank
                # a wide star's in the PSF estimate's choice of stars, and pass for a clip level).
                raw[i, j] += cleaned[i, j] - win[i, j]
    win[:, :] = cleaned
    return hit_any


@njit(cache=True)
def brightest_box(win, seed_half, row_lo, row_hi, col_lo, col_hi):
    """
    Return (sum, row, col) of the brightest (2 seed_half + 1)^2 box sum of `win`.

    Over the box centres in rows [row_lo, row_hi) and columns [col_lo, col_hi); row -1 if none.
    """
    best, br, bc = -np.inf, -1, -1
    for i in range(row_lo, row_hi):
        for j in range(col_lo, col_hi):
            total = np.float32(0.0)
            for a in range(-seed_half, seed_half + 1):
                for b in range(-seed_half, seed_half + 1):
                    total += np.float32(win[i + a, j + b])
            if total > best:
                best, br, bc = total, i, j
    return best, br, bc


@njit(cache=True)
def _measure_small(image, spots, settings):
    """
    Compute the point-window measurements of candidates.measure_candidates, compiled.

    Per spot n: a search window of (2 half + 1 + search_margin)^2 around (cx, cy) [px] minus
    bg [ADU], hot pixels cleaned (the 4-neighbour test of measure.clean_hot_pixels),
    re-centred on the brightest box sum (3x3, wider for wide PSFs) inside the footprint box
    (top/bottom/left/right, full-resolution px; the search window itself re-centred once on a
    seed beyond half a window from its border), then a (2 half + 1)^2 window measured in a
    circular aperture (measure.aperture_moments: centre of gravity, covariance, second moments; with `weighted`
    also the intensity-weighted centre), SNR in the near-optimal aperture, brightest raw
    value, edge flag. ratio_limit = inf switches the cleaning off. spots: SmallSpots;
    settings: PointWindowSettings. Returns a tuple of arrays in SmallSpotMeasurements' order.
    """
    cx, cy, bg, top, bottom, left, right = (spots.cx, spots.cy, spots.bg, spots.top, spots.bottom, spots.left,
                                            spots.right)
    bg_dx, bg_dy = spots.bg_dx, spots.bg_dy
    half, search_margin, sigma = settings.half, settings.search_margin, settings.sigma
    noise, gain, ratio_limit, weighted = settings.noise, settings.gain, settings.ratio_limit, settings.weighted
    height, width = image.shape
    n = cx.size
    size = 2 * half + 1
    big = size + search_margin
    r_ap = min(max(2.5, 3.0 * sigma), float(half))
    r_snr = max(1.5, 1.6 * sigma)
    # The seed box: 3x3, or the PSF's core for wide PSFs (a faint wide star's brightest 3x3 is noise
    # a pixel or two off its centre, and its SNR aperture with it).
    seed_half = max(1, int(sigma + 0.5))
    out_x = np.full(n, np.nan)
    out_y = np.full(n, np.nan)
    out_flux = np.full(n, np.nan)
    out_snr = np.full(n, np.nan)
    out_minor = np.full(n, np.nan)
    out_major = np.full(n, np.nan)
    out_angle = np.full(n, np.nan)
    out_peak = np.full(n, np.nan)
    out_peak_raw = np.full(n, np.nan)
    out_cov = np.full((n, 2, 2), np.nan)
    out_wx = np.full(n, np.nan)
    out_wy = np.full(n, np.nan)
    out_wcov = np.full((n, 2, 2), np.nan)
    out_edge = np.zeros(n, np.bool_)
    out_cleaned = np.zeros(n, np.bool_)
    windows = np.zeros((n, size, size))
    windows_valid = np.zeros((n, size, size), np.bool_)
    col0_out = np.zeros(n, np.int64)
    row0_out = np.zeros(n, np.int64)
    search = np.zeros((n, big, big))
    search_valid = np.zeros((n, big, big), np.bool_)
    c0_out = np.zeros(n, np.int64)
    r0_out = np.zeros(n, np.int64)
    raw = np.zeros((big, big))
    win = np.zeros((big, big))
    valid = np.zeros((big, big), np.bool_)
    lo, hi = half, big - 1 - half
    feat = np.ones(6)
    sig, var_sum, pos, sq, sq_var = np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6)
    for s in range(n):
        c0 = int(np.rint(cx[s])) - big // 2
        r0 = int(np.rint(cy[s])) - big // 2
        plane = (bg[s], cx[s], cy[s], bg_dx[s], bg_dy[s])
        hit_any = _clean_search_window(image, c0, r0, plane, ratio_limit, noise, raw, win, valid)
        # Seed: brightest box sum in the footprint box. The search window is centred on the
        # footprint's centroid; a star at one end of a long footprint (a faint wide star merged
        # with a hot pixel) can lie beyond the seeds kept half a window from its border: the window
        # is then centred on that star once and searched again, its seed kept from the border.
        best, br, bc = brightest_box(win, seed_half, max(top[s] - r0, seed_half), min(bottom[s] - r0, big - seed_half),
                                     max(left[s] - c0, seed_half), min(right[s] - c0, big - seed_half))
        if br >= 0 and not (lo <= br <= hi and lo <= bc <= hi):
            c0, r0 = c0 + bc - big // 2, r0 + br - big // 2
            hit_any = _clean_search_window(image, c0, r0, plane, ratio_limit, noise, raw, win, valid)
            best, br, bc = brightest_box(win, seed_half, min(max(top[s] - r0, lo), hi),
                                         min(max(bottom[s] - r0, lo + 1), hi + 1), min(max(left[s] - c0, lo), hi),
                                         min(max(right[s] - c0, lo + 1), hi + 1))
        c0_out[s], r0_out[s] = c0, r0
        out_cleaned[s] = hit_any
        search[s] = win
        search_valid[s] = valid
        if br < 0:
            continue
        col0, row0 = c0 + bc - half, r0 + br - half
        col0_out[s], row0_out[s] = col0, row0
        # Aperture sums (local coordinates of the spot window).
        # Sums over the aperture of weight x (1, x, y, x^2, y^2, xy): signal, its variance, the
        # positive signal (shape), squared signal and its variance (intensity-weighted centre).
        sig[:] = 0.0
        var_sum[:] = 0.0
        pos[:] = 0.0
        sq[:] = 0.0
        sq_var[:] = 0.0
        flux = 0.0
        peak = -np.inf
        peak_raw = -np.inf
        snr_signal = snr_var = 0.0
        all_valid = True
        for i in range(size):
            for j in range(size):
                value = win[br - half + i, bc - half + j]
                ok = valid[br - half + i, bc - half + j]
                windows[s, i, j] = value
                windows_valid[s, i, j] = ok
                if not ok:
                    all_valid = False
                    continue
                d = math.hypot(i - half, j - half)
                positive = max(value, 0.0)
                if d <= r_snr:
                    snr_signal += value
                    snr_var += positive / gain + noise * noise
                if d > r_ap:
                    continue
                feat[1], feat[2] = float(j), float(i)
                feat[3], feat[4], feat[5] = feat[1] * feat[1], feat[2] * feat[2], feat[1] * feat[2]
                var = positive / gain + noise * noise
                flux += value
                for k in range(6):
                    sig[k] += value * feat[k]
                    var_sum[k] += var * feat[k]
                    pos[k] += positive * feat[k]
                if weighted:
                    for k in range(6):
                        sq[k] += positive * positive * feat[k]
                        sq_var[k] += 4.0 * positive * positive * var * feat[k]
                if value > peak:
                    peak = value
                rv = raw[br - half + i, bc - half + j]
                if rv > peak_raw:
                    peak_raw = rv
        out_flux[s] = flux
        out_peak[s] = peak
        out_peak_raw[s] = peak_raw
        out_snr[s] = snr_signal / math.sqrt(snr_var) if snr_var > 0 else np.nan
        _centre_and_covariance(sig, var_sum, col0, row0, out_x, out_y, out_cov, s)
        # A centre of gravity outside its own aperture is no centre: a faint wide star's aperture
        # sum is mostly noise, and a sum near 0 sends it anywhere (70 px off a ring of SNR 11).
        # The aperture's centre, on the brightest box, is kept.
        if math.isfinite(out_x[s]) and math.hypot(out_x[s] - (col0 + half), out_y[s] - (row0 + half)) > r_ap:
            out_x[s], out_y[s] = float(col0 + half), float(row0 + half)
        if pos[0] > 0.0:
            px, py = pos[1] / pos[0], pos[2] / pos[0]
            mxx = pos[3] / pos[0] - px * px
            myy = pos[4] / pos[0] - py * py
            mxy = pos[5] / pos[0] - px * py
            spread = math.sqrt(0.25 * (mxx - myy) ** 2 + mxy * mxy)
            out_minor[s] = 0.5 * (mxx + myy) - spread
            out_major[s] = 0.5 * (mxx + myy) + spread
            out_angle[s] = 0.5 * math.atan2(2.0 * mxy, mxx - myy)
        if weighted:
            _centre_and_covariance(sq, sq_var, col0, row0, out_wx, out_wy, out_wcov, s)
        out_edge[s] = (not all_valid) or col0 <= 0 or row0 <= 0 or col0 + size >= width or row0 + size >= height
    return (out_x, out_y, out_flux, out_snr, out_minor, out_major, out_angle, out_peak, out_peak_raw, out_cov,
            out_wx, out_wy, out_wcov, out_edge, out_cleaned, windows, windows_valid, col0_out, row0_out,
            search, search_valid, c0_out, r0_out)


def warm_up() -> None:
    """Compile (or load from the cache) the measurement for every image dtype (passed read-only), and the seed box."""
    one = np.full(1, 16.0)
    index = np.full(1, 14, np.int64)
    for dtype in WARM_IMAGE_DTYPES:
        flat = np.zeros(1)
        spots = SmallSpots(one, one, flat, flat, flat, index, index + 4, index, index + 4)
        measure_small(np.zeros((32, 32), dtype), spots,
                      PointWindowSettings(4, 8, 1.0, 1.0, 1.0, 3.0, False))
    brightest_box(np.zeros((9, 9)), 1, 1, 8, 1, 8)  # candidates' wide spots call it on float64 windows
