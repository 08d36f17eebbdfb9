# SPDX-License-Identifier: Apache-2.0
"""
The accepted match's published fit, compiled: its screens and its fit each one call.

base.StarIdentifier's rules (its docstrings: verification_radius_px, without_lever_outlier,
without_unnameable, _fit, solved) run here on the flux-sorted spots' arrays (SpotGeometry), so that finishing a solve
costs a few compiled calls rather than dozens of small numpy ones. Rotations sensor -> ICRS;
rays and catalog vectors unit vectors; sigmas [rad]; pixel covariances [px^2]; jacobians
[rad/px]. An empty pixel_cov (0, 2, 2) means isotropic spots (sigma alone).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..models.attitude_estimation import refine_kernel


@njit(cache=True)
def match_chi2(rays, sigma, vectors, spot, star, rotation):
    """
    Return sum over the matches of (|b - R^T r| / sigma)^2: the match's own fit, in matching sigmas.

    rays (N, 3), sigma (N,) of the spots; vectors (S, 3) catalog; spot, star (M,) the matches.
    """
    total = 0.0
    for i in range(spot.size):
        s, t = spot[i], star[i]
        squared = 0.0
        for a in range(3):
            predicted = vectors[t, 0] * rotation[0, a] + vectors[t, 1] * rotation[1, a] + vectors[t, 2] * rotation[2, a]
            d = rays[s, a] - predicted
            squared += d * d
        z = math.sqrt(squared) / sigma[s]
        total += z * z
    return total


@njit(cache=True)
def nameable(pixel_cov, sigma, spot, pixel_scale, floor_px, density_px, gate_sigma, max_chance):
    """
    Return (M,) bool: the matched spots whose gate holds at most max_chance unrelated guide stars.

    A gate: the ellipse of gate_sigma sigmas of the spot's own covariance + floor_px^2 I
    (isotropic spots: sigma / pixel_scale [px]); its unrelated guide stars: density_px [1/px^2]
    times its area. A NaN covariance counts as unknown: kept.
    """
    keep = np.empty(spot.size, np.bool_)
    floor2 = floor_px * floor_px
    for i in range(spot.size):
        s = spot[i]
        if pixel_cov.shape[0] == 0:
            det = math.pow(sigma[s] / pixel_scale, 4.0)
        else:
            c00, c11 = pixel_cov[s, 0, 0] + floor2, pixel_cov[s, 1, 1] + floor2
            det = c00 * c11 - pixel_cov[s, 0, 1] * pixel_cov[s, 1, 0]
        if det < 0.0:
            det = 0.0
        chance = density_px * math.pi * gate_sigma ** 2 * math.sqrt(det)
        keep[i] = not chance > max_chance
    return keep


@njit(cache=True)
def published_fit(rays, sigma, pixel_cov, jacobian, spot, stars, rotation, screen_chi2, min_stars):
    """
    Fit the published attitude of matches: refine_kernel from `rotation`, then once more without the screened stars.

    spot (M,) into the spots; stars (M, 3) their ICRS vectors. Each ray weighted by its own
    covariance (pixel_cov through jacobian; isotropic: sigma^2 (I - b b^T)); stars whose
    studentized chi^2 exceeds screen_chi2 are left out of a second fit when at least
    min_stars stay. Returns rotation, covariance [rad^2], loss, studentized chi^2 (M,),
    residual angles (M,) [rad] (refine_kernel's).
    """
    n = spot.size
    body = np.empty((n, 3))
    for i in range(n):
        for a in range(3):
            body[i, a] = rays[spot[i], a]
    if pixel_cov.shape[0] == 0:
        cov = np.empty((n, 3, 3))
        jac = np.zeros((0, 3, 2))
        for i in range(n):
            s2 = sigma[spot[i]] * sigma[spot[i]]
            for r in range(3):
                for c in range(3):
                    cov[i, r, c] = s2 * ((1.0 if r == c else 0.0) - body[i, r] * body[i, c])
    else:
        cov = np.empty((n, 2, 2))
        jac = np.empty((n, 3, 2))
        for i in range(n):
            cov[i] = pixel_cov[spot[i]]
            jac[i] = jacobian[spot[i]]
    used = np.ones(n, np.bool_)
    fitted, covariance, loss, chi2, angle = refine_kernel(rotation, body, stars, cov, jac, used, 2)
    inliers = 0
    for i in range(n):
        used[i] = chi2[i] <= screen_chi2
        inliers += used[i]
    if inliers < n and inliers >= min_stars:
        fitted, covariance, loss, chi2, angle = refine_kernel(fitted, body, stars, cov, jac, used, 2)
    return fitted, covariance, loss, chi2, angle


@njit(cache=True)
def verification_radius_px(sigma, pixel_scale, match_radius_px):
    """
    Return the verification radius [px]: match_radius_px, widened to 4 sigma of the median spot.

    sigma (N,) the spots' matching sigmas [rad]; pixel_scale [rad/px]. match_radius_px when
    there are no spots.
    """
    n = sigma.size
    if n == 0:
        return match_radius_px
    return max(match_radius_px, 4.0 * (np.sort(sigma)[n // 2] / pixel_scale))


@njit(cache=True)
def guide_fit(prepared, spot, star, vectors, rotation, pixel_scale, unnameable, screen_chi2, min_stars):
    """
    StarIdentifier.solved's first steps on a match: leave out the unnameable guide stars, fit the published attitude.

    prepared: PreparedSpots; spot, star (M,) the match (star: rows of `vectors` (S, 3), ICRS);
    rotation (sensor -> ICRS) its matching fit; unnameable: (floor_px, density_px, gate_sigma,
    max_chance) (StarIdentifier.unnameable_settings). Returns (guide spot, guide star, guide
    stars left out, their vectors, fitted rotation, its covariance [rad^2] (C order), loss,
    residual angles [rad]).
    """
    floor_px, density_px, gate_sigma, max_chance = unnameable
    count = spot.size
    guide_spot, guide_star, too_uncertain = spot, star, 0
    if count > min_stars:
        keep = nameable(prepared.pixel_cov, prepared.sigma, spot, pixel_scale, floor_px, density_px, gate_sigma,
                        max_chance)
        kept = int(np.count_nonzero(keep))
        if kept < count and kept >= min_stars:
            guide_spot, guide_star, too_uncertain = spot[keep], star[keep], count - kept
    guide_vectors = np.empty((guide_spot.size, 3))
    for i in range(guide_spot.size):
        guide_vectors[i] = vectors[guide_star[i]]
    fitted, covariance, loss, _, residual = published_fit(prepared.rays, prepared.sigma, prepared.pixel_cov,
                                                          prepared.jacobian, guide_spot, guide_vectors, rotation,
                                                          screen_chi2, min_stars)
    return (guide_spot, guide_star, too_uncertain, guide_vectors, fitted, np.ascontiguousarray(covariance), loss,
            residual)


@njit(cache=True)
def any_beyond(residual, sigma, spot, limit):
    """Whether any match's residual [rad] exceeds `limit` times its spot's sigma (spot (M,) into sigma)."""
    for i in range(spot.size):
        if residual[i] / sigma[spot[i]] > limit:
            return True
    return False


def warm_up() -> None:
    """Compile (or load) the kernels the Python steps call (StarIdentifier), with the argument types they pass."""
    n = 6
    angle = np.linspace(-0.05, 0.05, n)
    rays = np.ascontiguousarray(np.stack([np.sin(angle), np.sin(angle[::-1]) * 0.5, np.ones(n)], axis=1))
    rays /= np.linalg.norm(rays, axis=1)[:, None]
    sigma = np.full(n, 1e-4)
    spot = np.arange(n, dtype=np.int64)
    pixel_cov = np.tile(np.eye(2) * 0.01, (n, 1, 1))
    jacobian = np.zeros((n, 3, 2))
    jacobian[:, 0, 0] = jacobian[:, 1, 1] = 1e-4
    rotation = np.eye(3)
    match_chi2(rays, sigma, rays, spot, spot, rotation)
    nameable(pixel_cov, sigma, spot, 1e-4, 0.1, 1e-6, 5.0, 0.01)
    published_fit(rays, sigma, pixel_cov, jacobian, spot, rays.copy(), rotation, 13.8, 4)
    verification_radius_px(sigma, 1e-4, 2.0)
