# SPDX-License-Identifier: Apache-2.0
"""
Compiled inner loops of the centroider (numba).

The per-spot work that is too small for numpy's per-call overhead to pay off. Compiled on
first use and cached on disk next to this module (or in NUMBA_CACHE_DIR).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .hot_pixel_kernel import is_hot, neighbour_mean
from .hot_pixel_kernel import warm_up as warm_hot_pixel_test

_INV_ROOT2 = 1.0 / math.sqrt(2.0)
_INV_ROOT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


@njit(cache=True, fastmath=False)
def _profile(lo: float, centre: float, sigma: float, size: int, prob: np.ndarray, deriv: np.ndarray) -> None:
    """
    Fraction of a 1-D Gaussian in pixels [lo + k, lo + k + 1) and its derivative with respect to the centre.

    For k = 0..size-1 (see psf_fit.pixel_integrated_profile).
    """
    for k in range(size):
        a = (lo + k - centre) / sigma
        b = a + 1.0 / sigma
        prob[k] = 0.5 * (math.erf(b * _INV_ROOT2) - math.erf(a * _INV_ROOT2))
        deriv[k] = (math.exp(-0.5 * a * a) - math.exp(-0.5 * b * b)) * (_INV_ROOT_2PI / sigma)


@njit(cache=True, fastmath=False)
def invert_3x3(a: np.ndarray, out: np.ndarray) -> bool:
    """Write the inverse of the 3x3 matrix `a` into `out` by cofactors; False (out unchanged) when singular."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    if not (det != 0.0 and math.isfinite(det)):
        return False
    out[0, 0], out[1, 0], out[2, 0] = c00 / det, c01 / det, c02 / det
    out[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) / det
    out[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) / det
    out[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) / det
    out[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) / det
    out[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) / det
    out[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) / det
    return True


@njit(cache=True, fastmath=False)
def fit_single_psf(windows, start, settings):
    """
    One pixel-integrated Gaussian PSF per window.

    The same weighted Gauss-Newton as psf_fit.fit_psf_windows with M = 1 (1 px trust region,
    1e-9 relative damping, stop when the position step is below 1 % of its sigma, covariance
    from the last step's inverse). windows: psf_fit.PsfWindows, data float64 and valid bool
    (n, S, S), col0, row0 float64 (n,); start: psf_fit.PsfStart of (n,) arrays; settings:
    psf_fit.PsfSettings (halo components: the core and halo Gaussians of core_halo_psf).
    Returns x, y, flux (n,), cov (n, 2, 2), flux_var (n,), converged (n,).
    """
    data, valid, col0, row0 = windows.data, windows.valid, windows.col0, windows.row0
    x0, y0, flux0 = start.x, start.y, start.flux
    sigma, noise, gain, iterations = settings.sigma, settings.noise, settings.gain, settings.iterations
    halo_sigmas, halo_shares = settings.halo_sigmas, settings.halo_shares
    halos = halo_sigmas.size
    core_share = 1.0 - halo_shares.sum()
    n, size, _ = data.shape
    x, y, flux = x0.copy(), y0.copy(), np.maximum(flux0.copy(), 1e-9)
    cov = np.full((n, 2, 2), np.nan)
    flux_var = np.full(n, np.nan)
    converged = np.zeros(n, np.bool_)
    px = np.empty(size)
    dpx = np.empty(size)
    py = np.empty(size)
    dpy = np.empty(size)
    hx, dhx = np.empty((halos, size)), np.empty((halos, size))  # the halo Gaussians' profiles
    hy, dhy = np.empty((halos, size)), np.empty((halos, size))
    normal = np.empty((3, 3))
    inv = np.empty((3, 3))
    grad = np.empty(3)
    jac = np.empty(3)
    for s in range(n):
        for _ in range(iterations):
            _profile(col0[s] - 0.5, x[s], sigma, size, px, dpx)
            _profile(row0[s] - 0.5, y[s], sigma, size, py, dpy)
            for h in range(halos):
                _profile(col0[s] - 0.5, x[s], halo_sigmas[h], size, hx[h], dhx[h])
                _profile(row0[s] - 0.5, y[s], halo_sigmas[h], size, hy[h], dhy[h])
            normal[:, :] = 0.0
            grad[:] = 0.0
            f = flux[s]
            for i in range(size):
                for j in range(size):
                    if not valid[s, i, j]:
                        continue
                    if halos:
                        shape = core_share * py[i] * px[j]
                        slope_x = core_share * py[i] * dpx[j]
                        slope_y = core_share * dpy[i] * px[j]
                        for h in range(halos):
                            shape += halo_shares[h] * hy[h, i] * hx[h, j]
                            slope_x += halo_shares[h] * hy[h, i] * dhx[h, j]
                            slope_y += halo_shares[h] * dhy[h, i] * hx[h, j]
                        jac[0] = f * slope_x
                        jac[1] = f * slope_y
                    else:
                        shape = py[i] * px[j]
                        jac[0] = f * py[i] * dpx[j]
                        jac[1] = f * dpy[i] * px[j]
                    model = f * shape
                    weight = 1.0 / (max(model, 0.0) / gain + noise * noise)
                    jac[2] = shape
                    resid = data[s, i, j] - model
                    for a in range(3):
                        wa = weight * jac[a]
                        grad[a] += wa * resid
                        for b in range(a, 3):
                            normal[a, b] += wa * jac[b]
            for a in range(3):
                for b in range(a):
                    normal[a, b] = normal[b, a]
                normal[a, a] += 1e-9 * abs(normal[a, a]) + 1e-300
            if not invert_3x3(normal, inv):
                break
            step_x = inv[0, 0] * grad[0] + inv[0, 1] * grad[1] + inv[0, 2] * grad[2]
            step_y = inv[1, 0] * grad[0] + inv[1, 1] * grad[1] + inv[1, 2] * grad[2]
            step_f = inv[2, 0] * grad[0] + inv[2, 1] * grad[1] + inv[2, 2] * grad[2]
            step_x = min(max(step_x, -1.0), 1.0)
            step_y = min(max(step_y, -1.0), 1.0)
            x[s] += step_x
            y[s] += step_y
            flux[s] = max(flux[s] + step_f, 1e-9)
            cov[s, 0, 0], cov[s, 0, 1], cov[s, 1, 0], cov[s, 1, 1] = inv[0, 0], inv[0, 1], inv[1, 0], inv[1, 1]
            flux_var[s] = inv[2, 2]
            if (step_x * step_x <= max(1e-4 * abs(inv[0, 0]), 1e-10)
                    and step_y * step_y <= max(1e-4 * abs(inv[1, 1]), 1e-10)):
                break
        converged[s] = (math.isfinite(cov[s, 0, 0]) and math.isfinite(cov[s, 1, 1]) and math.isfinite(cov[s, 0, 1])
                        and cov[s, 0, 0] > 0 and cov[s, 1, 1] > 0 and math.isfinite(x[s]) and math.isfinite(y[s])
                        and col0[s] + 0.5 < x[s] < col0[s] + size - 1.5 and row0[s] + 0.5 < y[s] < row0[s] + size - 1.5)
    return x, y, flux, cov, flux_var, converged


WARM_IMAGE_DTYPES = (np.uint16, np.uint8, np.float32)  # what the nodes and the CLI pass to extract_spots


def warm_up() -> None:
    """Compile (or load from the cache) every kernel now, not on the first frame."""
    from .psf_fit import PsfSettings, PsfStart, PsfWindows

    data = np.zeros((1, 7, 7))
    data[0, 3, 3] = 100.0
    fit_single_psf(PsfWindows(data, np.ones((1, 7, 7), np.bool_), np.zeros(1), np.zeros(1)),
                   PsfStart(np.full(1, 3.0), np.full(1, 3.0), np.full(1, 100.0)),
                   PsfSettings(1.0, 1.0, 1.0, 5))
    component_stats(np.zeros((4, 4), np.int32), 1)
    from .blend_fit_kernel import fit_multi_psf

    pair = np.full((1, 2), 3.0)
    fit_multi_psf(data, np.ones((1, 7, 7), np.bool_), np.zeros(1), np.zeros(1), pair, pair, pair * 30.0, 1.0, 1.0,
                  1.0, 2)
    from .elliptical_psf import EllipticalGaussianPsf, fit_elliptical

    fit_elliptical(EllipticalGaussianPsf(1.5, 1.0, 0.3), data, np.ones((1, 7, 7), np.bool_), np.zeros(1), np.zeros(1),
                   np.full(1, 3.0), np.full(1, 3.0), np.full(1, 100.0), 1.0, 1.0)
    fit_psf_width(data, np.ones((1, 7, 7), np.bool_), np.zeros(1), np.zeros(1), np.full(1, 3.0), np.full(1, 3.0),
                  np.full(1, 100.0), np.full(1, 1.0), 1.0, 1.0, 5)
    one = np.full(1, 16.0)
    index = np.full(1, 14, np.int64)
    from .peak_shape_kernel import own_pixel_moments

    two_peaks = np.array([[3.0, 3.0], [5.0, 4.0]])
    for dtype in WARM_IMAGE_DTYPES:  # measure_small passes every image read-only: one variant per dtype
        own_pixel_moments(read_only(np.zeros((8, 8), dtype)), np.zeros(2), two_peaks, 2.0, 2, 1.0, 1.0, 1)
        measure_small(np.zeros((32, 32), dtype), SmallSpots(one, one, np.zeros(1), index, index + 4, index, index + 4),
                      PointWindowSettings(4, 8, 1.0, 1.0, 1.0, 3.0, False))
        footprint_peaks(np.zeros((32, 32), dtype), np.zeros((16, 16), np.int32), 2, np.ones(1, np.int64), index,
                        index, index + 4, index + 4)
    from .streak_free_fit import fit_streaks

    warm_hot_pixel_test()

    streak = np.zeros((24, 24), np.float32)  # fit_streaks hands the kernel float32 windows whatever the image
    streak[12, 8:16] = 100.0
    fit_streaks(streak, [12.0], [12.0], [800.0], [8.0], [0.0], 1.0, 1.0, 1.0, iterations=2)


@njit(cache=True)
def footprint_peaks(image: np.ndarray, labels: np.ndarray, binning: int, label: np.ndarray, left: np.ndarray,
                    top: np.ndarray, right: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """
    Highest raw value [ADU] of each detection's footprint pixels (-inf: none).

    labels: the component label image on the binning x binning grid; label, left, top, right,
    bottom: each detection's label and full-resolution bounding box (right/bottom exclusive).
    """
    rows, cols = labels.shape
    out = np.full(label.size, -np.inf)
    for k in range(label.size):
        best = -np.inf
        for r in range(top[k], bottom[k]):
            lr = min(r // binning, rows - 1)
            for c in range(left[k], right[k]):
                if labels[lr, min(c // binning, cols - 1)] == label[k] and image[r, c] > best:
                    best = image[r, c]
        out[k] = best
    return out


@njit(cache=True)
def component_stats(labels: np.ndarray, count: int):
    """
    Bounding box, pixel count and centroid of each label of a label image, in one pass.

    Box (left, top, right, bottom; exclusive), pixel count and centroid (x, y) of each label
    1..count-1, in one pass
    (OpenCV's WithStats variant is slower for the few, small components of a star field).
    """
    height, width = labels.shape
    left = np.full(count, width, np.int64)
    top = np.full(count, height, np.int64)
    right = np.zeros(count, np.int64)
    bottom = np.zeros(count, np.int64)
    area = np.zeros(count, np.int64)
    sum_x = np.zeros(count)
    sum_y = np.zeros(count)
    for r in range(height):
        for c in range(width):
            k = labels[r, c]
            if k == 0:
                continue
            if c < left[k]:
                left[k] = c
            if c >= right[k]:
                right[k] = c + 1
            if r < top[k]:
                top[k] = r
            if r >= bottom[k]:
                bottom[k] = r + 1
            area[k] += 1
            sum_x[k] += c
            sum_y[k] += r
    return left, top, right, bottom, area, sum_x / np.maximum(area, 1), sum_y / np.maximum(area, 1)


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

    cx, cy the footprint centroid [px]; bg the background there [ADU]; top, bottom, left,
    right its bounding box (full-resolution px, bottom/right exclusive; int64).
    """

    cx: np.ndarray
    cy: np.ndarray
    bg: np.ndarray
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


def read_only(image: np.ndarray) -> np.ndarray:
    """
    `image` as a read-only array (a view when it is writeable, no copy).

    Read-only and writeable arrays are distinct numba types: passing one kind halves the
    variants compiled (each took ~10 s at a cold start).
    """
    if not image.flags.writeable:
        return image
    view = image.view()
    view.flags.writeable = False
    return view


@njit(cache=True)
def _clean_search_window(image, c0, r0, bg, ratio_limit, noise, raw, win, valid):
    """
    Fill the search window (top-left pixel (c0, r0)) from `image` less `bg`, hot pixels cleaned.

    raw, win, valid (big, big) are overwritten; returns whether a hot pixel was cleaned. The
    4-neighbour test of measure.clean_hot_pixels (hot_pixel_kernel.is_hot, neighbour_mean):
    interior rows only (as the stacked OpenCV pass), replicate at the columns.
    """
    height, width = image.shape
    big = win.shape[0]
    for i in range(big):
        for j in range(big):
            rr, cc = r0 + i, c0 + j
            inside = 0 <= rr < height and 0 <= cc < width
            valid[i, j] = inside
            raw[i, j] = float(image[min(max(rr, 0), height - 1), min(max(cc, 0), width - 1)]) if inside else 0.0
            win[i, j] = raw[i, j] - bg if inside else 0.0
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
        hit_any = _clean_search_window(image, c0, r0, bg[s], ratio_limit, noise, raw, win, valid)
        # Seed: brightest box sum in the footprint box. The search window is centred on the
        # footprint's centroid; a star at one end of a long footprint (a faint wide star merged
        # with a hot pixel) can lie beyond the seeds kept half a window from its border: the window
        # is then centred on that star once and searched again, its seed kept from the border.
        best, br, bc = brightest_box(win, seed_half, max(top[s] - r0, seed_half), min(bottom[s] - r0, big - seed_half),
                                     max(left[s] - c0, seed_half), min(right[s] - c0, big - seed_half))
        if br >= 0 and not (lo <= br <= hi and lo <= bc <= hi):
            c0, r0 = c0 + bc - big // 2, r0 + br - big // 2
            hit_any = _clean_search_window(image, c0, r0, bg[s], ratio_limit, noise, raw, win, valid)
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


@njit(cache=True, fastmath=False)
def _profile_with_width(lo: float, centre: float, sigma: float, size: int, prob: np.ndarray, d_centre: np.ndarray,
                        d_sigma: np.ndarray) -> None:
    """_profile plus the derivative of each pixel's fraction with respect to sigma [1/px]."""
    for k in range(size):
        a = (lo + k - centre) / sigma
        b = a + 1.0 / sigma
        pa = math.exp(-0.5 * a * a) * _INV_ROOT_2PI
        pb = math.exp(-0.5 * b * b) * _INV_ROOT_2PI
        prob[k] = 0.5 * (math.erf(b * _INV_ROOT2) - math.erf(a * _INV_ROOT2))
        d_centre[k] = (pa - pb) / sigma
        d_sigma[k] = (a * pa - b * pb) / sigma


@njit(cache=True)
def _solve_spd(normal: np.ndarray, rhs: np.ndarray, out: np.ndarray) -> bool:
    """
    Solve out = normal^-1 rhs by Cholesky (normal symmetric positive definite, overwritten by its factor).

    False when it is not positive definite.
    """
    n = rhs.size
    for j in range(n):
        d = normal[j, j]
        for k in range(j):
            d -= normal[j, k] * normal[j, k]
        if not (d > 0.0 and math.isfinite(d)):
            return False
        d = math.sqrt(d)
        normal[j, j] = d
        for i in range(j + 1, n):
            v = normal[i, j]
            for k in range(j):
                v -= normal[i, k] * normal[j, k]
            normal[i, j] = v / d
    for i in range(n):
        v = rhs[i]
        for k in range(i):
            v -= normal[i, k] * out[k]
        out[i] = v / normal[i, i]
    for i in range(n - 1, -1, -1):
        v = out[i]
        for k in range(i + 1, n):
            v -= normal[k, i] * out[k]
        out[i] = v / normal[i, i]
    return True


@njit(cache=True, fastmath=False)
def fit_psf_width(data, valid, col0, row0, x0, y0, flux0, sigma0, noise, gain, iterations):
    """
    One pixel-integrated circular Gaussian per window with free width and a constant background offset.

    Parameters (x, y [px], flux [ADU], sigma [px], offset [ADU]) by weighted Gauss-Newton
    (weights 1 / (star model / gain + noise^2)), 1 px trust region on the centre, sigma kept in
    [0.1, 12] px and changed by at most half of itself per step; converged when a step moves
    the centre < 0.01 px and sigma < 0.2 % (the estimate is a median over stars). data (n, S,
    S) background-subtracted windows [ADU], valid (n, S, S) bool, col0/row0 (n,) top-left
    pixels [px]; starts x0, y0, flux0, sigma0 (n,). Returns x, y, flux, sigma (n,), sigma_var
    (n,) [px^2] (inverse Fisher information), chi2 (n,) (reduced: per degree of freedom),
    converged (n,).
    """
    n, size, _ = data.shape
    x, y, flux, sigma = x0.copy(), y0.copy(), np.maximum(flux0.copy(), 1e-9), sigma0.copy()
    offset = np.zeros(n)
    sigma_var = np.full(n, np.nan)
    chi2 = np.full(n, np.nan)
    converged = np.zeros(n, np.bool_)
    px, dpx, spx = np.empty(size), np.empty(size), np.empty(size)
    py, dpy, spy = np.empty(size), np.empty(size), np.empty(size)
    normal, work = np.empty((5, 5)), np.empty((5, 5))
    grad, jac, step, unit = np.empty(5), np.empty(5), np.empty(5), np.empty(5)
    for s in range(n):
        done = False
        for _ in range(iterations):
            _profile_with_width(col0[s] - 0.5, x[s], sigma[s], size, px, dpx, spx)
            _profile_with_width(row0[s] - 0.5, y[s], sigma[s], size, py, dpy, spy)
            normal[:, :] = 0.0
            grad[:] = 0.0
            f = flux[s]
            for i in range(size):
                for j in range(size):
                    if not valid[s, i, j]:
                        continue
                    star = f * py[i] * px[j]
                    weight = 1.0 / (max(star, 0.0) / gain + noise * noise)
                    jac[0] = f * py[i] * dpx[j]
                    jac[1] = f * dpy[i] * px[j]
                    jac[2] = py[i] * px[j]
                    jac[3] = f * (spy[i] * px[j] + py[i] * spx[j])
                    jac[4] = 1.0
                    resid = data[s, i, j] - star - offset[s]
                    for a in range(5):
                        wa = weight * jac[a]
                        grad[a] += wa * resid
                        for b in range(a, 5):
                            normal[a, b] += wa * jac[b]
            for a in range(5):
                for b in range(a):
                    normal[a, b] = normal[b, a]
                normal[a, a] += 1e-9 * abs(normal[a, a]) + 1e-300
            work[:, :] = normal
            if not _solve_spd(work, grad, step):
                break
            step[0] = min(max(step[0], -1.0), 1.0)
            step[1] = min(max(step[1], -1.0), 1.0)
            step[3] = min(max(step[3], -0.5 * sigma[s]), 0.5 * sigma[s])
            x[s] += step[0]
            y[s] += step[1]
            flux[s] = max(flux[s] + step[2], 1e-9)
            sigma[s] = min(max(sigma[s] + step[3], 0.1), 12.0)
            offset[s] += step[4]
            if abs(step[0]) < 1e-2 and abs(step[1]) < 1e-2 and abs(step[3]) < 2e-3 * sigma[s]:
                done = True
                break
        if not done:
            continue
        # The width's variance: the (sigma, sigma) element of the inverse information.
        work[:, :] = normal
        unit[:] = 0.0
        unit[3] = 1.0
        if not _solve_spd(work, unit, step):
            continue
        sigma_var[s] = step[3]
        _profile_with_width(col0[s] - 0.5, x[s], sigma[s], size, px, dpx, spx)
        _profile_with_width(row0[s] - 0.5, y[s], sigma[s], size, py, dpy, spy)
        total, count = 0.0, 0
        for i in range(size):
            for j in range(size):
                if valid[s, i, j]:
                    star = flux[s] * py[i] * px[j]
                    resid = data[s, i, j] - star - offset[s]
                    total += resid * resid / (max(star, 0.0) / gain + noise * noise)
                    count += 1
        chi2[s] = total / max(count - 5, 1)
        converged[s] = (math.isfinite(x[s]) and math.isfinite(y[s]) and col0[s] + 0.5 < x[s] < col0[s] + size - 1.5
                        and row0[s] + 0.5 < y[s] < row0[s] + size - 1.5 and sigma_var[s] > 0.0)
    return x, y, flux, sigma, sigma_var, chi2, converged
