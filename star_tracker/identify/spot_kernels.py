# SPDX-License-Identifier: Apache-2.0
"""
Compiled spot preparation for cameras without distortion (base.StarIdentifier.prepare).

Usable spots sorted by flux, their rays, matching sigmas, magnitudes, final-fit covariances
and ray jacobians, in one pass.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kernel_records import PreparedSpots


@njit(cache=True)
def prepare_spots(raw, camera, settings):
    """
    Return the compiled form of StarIdentifier.prepare for cameras without distortion (Pinhole), as PreparedSpots.

    Indices of the usable spots (RawSpots: finite, not coincident: coincident_later) sorted by
    flux (brightest first, NaN flux last, stable), their unit rays (N, 3), 1-sigma direction
    errors [rad] for matching (floored at sigma_floor_px), instrumental magnitudes (NaN for
    flux <= 0), pixel positions x, y [px], pixel covariances for the final fit (N, 2, 2)
    [px^2] (unknown: 1 px^2, plus min_fit_sigma_px^2 on both axes) and the rays' pixel
    jacobians (N, 3, 2) [rad/px] (PrepareSettings: the floors).
    """
    x, y, flux, cov = raw.x, raw.y, raw.flux, raw.cov
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    sigma_floor_px, min_fit_sigma_px = settings.sigma_floor_px, settings.min_fit_sigma_px
    n = x.size
    dropped = coincident_later(x, y, settings.separation_px)
    keep = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        if np.isfinite(x[i]) and np.isfinite(y[i]) and not dropped[i]:
            keep[m] = i
            m += 1
    key = np.empty(m)
    for q in range(m):
        f = flux[keep[q]]
        key[q] = -f if not np.isnan(f) else np.inf
    order = keep[:m][np.argsort(key, kind="mergesort")]
    rays = np.empty((m, 3))
    sigma = np.empty(m)
    magnitude = np.empty(m)
    xs = np.empty(m)
    ys = np.empty(m)
    pixel_cov = np.empty((m, 2, 2))
    scale = 1.0 / math.sqrt(fx * fy)
    extra = min_fit_sigma_px * min_fit_sigma_px
    for q in range(m):
        i = order[q]
        xs[q], ys[q] = x[i], y[i]
        u = (x[i] - cx) / fx
        v = (y[i] - cy) / fy
        norm = math.sqrt(u * u + v * v + 1.0)
        rays[q, 0], rays[q, 1], rays[q, 2] = u / norm, v / norm, 1.0 / norm
        variance = 0.5 * (cov[i, 0, 0] + cov[i, 1, 1])
        s = math.sqrt(max(variance, 0.0)) if math.isfinite(variance) else 1.0  # unknown: 1 px
        sigma[q] = max(s, sigma_floor_px) * scale
        magnitude[q] = -2.5 * math.log10(flux[i]) if flux[i] > 0 else np.nan
        known = (math.isfinite(cov[i, 0, 0]) and math.isfinite(cov[i, 0, 1]) and math.isfinite(cov[i, 1, 0])
                 and math.isfinite(cov[i, 1, 1]))
        for r in range(2):
            for c in range(2):
                pixel_cov[q, r, c] = (cov[i, r, c] if known else (1.0 if r == c else 0.0)) + (extra if r == c else 0.0)
    return PreparedSpots(order, rays, sigma, magnitude, xs, ys, pixel_cov, pinhole_jacobian(rays, fx, fy))


@njit(cache=True)
def pinhole_jacobian(rays, fx, fy):
    """(N, 3, 2) d ray / d pixel [rad/px] of pinhole unit rays (N, 3): r_z (I - r r^T)[:, :2] diag(1/fx, 1/fy)."""
    out = np.empty((rays.shape[0], 3, 2))
    for i in range(rays.shape[0]):
        a, b = rays[i, 2] / fx, rays[i, 2] / fy
        for r in range(3):
            out[i, r, 0] = a * ((1.0 if r == 0 else 0.0) - rays[i, r] * rays[i, 0])
            out[i, r, 1] = b * ((1.0 if r == 1 else 0.0) - rays[i, r] * rays[i, 1])
    return out


@njit(cache=True)
def coincident_later(x, y, separation_px):
    """
    (N,) bool: spots within separation_px [px] of an earlier (lower-index) finite spot.

    Sweep over x-sorted finite spots, O(N log N) for spread-out spots.
    """
    n = x.size
    dropped = np.zeros(n, np.bool_)
    finite = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        if np.isfinite(x[i]) and np.isfinite(y[i]):
            finite[m] = i
            m += 1
    by_x = finite[:m][np.argsort(x[finite[:m]], kind="mergesort")]
    limit = separation_px * separation_px
    for a in range(m):
        i = by_x[a]
        for b in range(a + 1, m):
            j = by_x[b]
            dx = x[j] - x[i]
            if dx > separation_px:
                break
            dy = y[j] - y[i]
            if dx * dx + dy * dy <= limit:
                dropped[max(i, j)] = True
    return dropped
