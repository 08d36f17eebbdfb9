# SPDX-License-Identifier: Apache-2.0
"""
Compiled kernels of local recognition (tracking.py).

The chance-match volume of the searched attitude region, one-to-one nearest pairs, the
catalog stars in a predicted view and an attitude's Mahalanobis offset from the prediction.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..identify.kernels import LN_8PI2, log_chance_tuples


@njit(cache=True)
def log_chance_tuples_in_region(body, sigma, chi2, density, region_covariance, region_sigma):
    """
    Return ln of the expected chance m-tuples fitting `body` with chi^2 <= `chi2` in a region.

    Under an attitude inside the region_sigma ellipsoid of `region_covariance` [rad^2]:
    log_chance_tuples with the volume of SO(3) replaced by the searched region when that is smaller (see
    tracking.log_chance_tuples_in_region for the math).
    """
    whole = log_chance_tuples(body, sigma, chi2, density)
    m = body.shape[0]
    info = np.zeros((3, 3))
    for i in range(m):
        w = 1.0 / (sigma[i] * sigma[i])
        for r in range(3):
            for c in range(3):
                info[r, c] += w * ((1.0 if r == c else 0.0) - body[i, r] * body[i, c])
    det = np.linalg.det(info)
    if det <= 0.0:
        return whole
    # Eigenvalues of G P through the symmetric L^T G L (P = L L^T).
    lower = np.linalg.cholesky(region_covariance)
    mu = np.linalg.eigvalsh(lower.T @ info @ lower)
    radius = math.sqrt(max(chi2, 1e-12))
    log_region = math.log(4.0 / 3.0 * math.pi)
    for i in range(3):
        log_region += math.log(region_sigma * math.sqrt(max(mu[i], 0.0)) + radius)
    return whole + min(0.0, log_region - (LN_8PI2 + 0.5 * math.log(det)))


@njit(cache=True)
def unique_nearest(spot_x, spot_y, ref_x, ref_y, radius):
    """
    One-to-one pairs within `radius` [px].

    A spot with exactly one reference within the radius, whose reference has no other spot
    within it. Returns (spot idx, ref idx).
    """
    n, m = spot_x.size, ref_x.size
    r2 = radius * radius
    refs_near_spot = np.zeros(n, np.int64)
    spots_near_ref = np.zeros(m, np.int64)
    nearest = np.full(n, -1, np.int64)
    for i in range(n):
        for j in range(m):
            dx = spot_x[i] - ref_x[j]
            dy = spot_y[i] - ref_y[j]
            if dx * dx + dy * dy <= r2:
                refs_near_spot[i] += 1
                spots_near_ref[j] += 1
                nearest[i] = j
    count = 0
    out_spot = np.empty(n, np.int64)
    out_ref = np.empty(n, np.int64)
    for i in range(n):
        if refs_near_spot[i] == 1 and spots_near_ref[nearest[i]] == 1:
            out_spot[count] = i
            out_ref[count] = nearest[i]
            count += 1
    return out_spot[:count], out_ref[:count]


@njit(cache=True)
def stars_in_view(vectors, rotation, cos_reach, camera, margin):
    """
    Catalog stars (ICRS unit vectors) a pinhole camera at `rotation` sees: (indices, u, v [px]).

    Those within acos(cos_reach) of the boresight of `rotation` (sensor -> ICRS) that the camera
    (Pinhole) puts inside its pixel area shrunk by `margin` [px] (negative: grown). One pass over the catalog (~8k
    stars).
    """
    fx, fy, cx, cy, width, height = camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height
    n = vectors.shape[0]
    near = np.empty(n, np.int64)
    us = np.empty(n)
    vs = np.empty(n)
    count = 0
    bx, by, bz = rotation[0, 2], rotation[1, 2], rotation[2, 2]
    for s in range(n):
        z = vectors[s, 0] * bx + vectors[s, 1] * by + vectors[s, 2] * bz
        if z <= cos_reach or z <= 1e-9:
            continue
        x = vectors[s, 0] * rotation[0, 0] + vectors[s, 1] * rotation[1, 0] + vectors[s, 2] * rotation[2, 0]
        y = vectors[s, 0] * rotation[0, 1] + vectors[s, 1] * rotation[1, 1] + vectors[s, 2] * rotation[2, 1]
        u = fx * x / z + cx
        v = fy * y / z + cy
        if -0.5 + margin <= u <= width - 0.5 - margin and -0.5 + margin <= v <= height - 0.5 - margin:
            near[count], us[count], vs[count] = s, u, v
            count += 1
    return near[:count].copy(), us[:count].copy(), vs[:count].copy()


@njit(cache=True)
def offset_mahalanobis2(predicted, rotation, covariance):
    """
    Squared Mahalanobis distance of `rotation` from `predicted` (both sensor -> ICRS).

    The rotation vector of predicted^T rotation [rad] (sensor frame) against `covariance`
    [rad^2].
    """
    rel = predicted.T @ rotation
    sx = 0.5 * (rel[2, 1] - rel[1, 2])
    sy = 0.5 * (rel[0, 2] - rel[2, 0])
    sz = 0.5 * (rel[1, 0] - rel[0, 1])
    cos = max(-1.0, min(1.0, 0.5 * (rel[0, 0] + rel[1, 1] + rel[2, 2] - 1.0)))
    sin = math.sqrt(sx * sx + sy * sy + sz * sz)
    angle = math.atan2(sin, cos)
    offset = np.empty(3)
    if sin > 1e-12:
        scale = angle / sin
        offset[0], offset[1], offset[2] = sx * scale, sy * scale, sz * scale
    elif cos > 0.0:
        offset[0], offset[1], offset[2] = sx, sy, sz
    else:  # a half turn: far outside any gate
        return np.inf
    return offset @ np.linalg.solve(covariance, offset)
