# SPDX-License-Identifier: Apache-2.0
"""
A tracked frame's local recognition in one compiled call: Tracker.track's common path, spots to published fit.

For a camera without distortion: the spots prepared (identify.spot_kernels), the gate, the
catalog stars the prediction puts in view, the nearest pairs (a small gate: no displacement
vote), their q-method attitude, the verification (one match pass), the offset from the
prediction, the region's false-positive bound, then what StarIdentifier.solved does for a
tracked frame: the guide stars too uncertain to name left out and the published fit. Each
step calls the kernel Tracker.track and StarIdentifier.solved call, with the same arguments,
so the result is the same to the bit (test_recognize_kernel). A wide gate's displacement is
voted in Python (tracking.vote_displacement), and from_pairs goes on from the vote; a guide
star to name again is left to StarIdentifier.solved.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..identify.final_fit_kernel import any_beyond, guide_fit, verification_radius_px
from ..identify.kernel_records import SpotArrays, VerifySettings
from ..identify.kernels import false_positive_bound, log_magnitude_agreement, q_method, verify_candidate
from ..identify.skygrid import cell_of
from ..identify.spot_kernels import prepare_spots
from .kernels import log_chance_tuples_in_region, offset_mahalanobis2, stars_in_view, unique_nearest

# recognize's verdicts: the frame solved, in Python, or the reason it failed (Tracker.track's messages).
SOLVED = 0
VOTE_IN_PYTHON = 1  # a wide gate: the displacement is voted (Tracker.track)
NAME_IN_PYTHON = 8  # a guide star beyond outlier_sigma of the fit: StarIdentifier.solved names the stars again
TOO_FEW_SPOTS = 2
TOO_FEW_STARS_NEAR = 3
TOO_FEW_PAIRS = 4
TOO_FEW_VERIFIED = 5
OUTSIDE_GATE = 6
BOUND_FAILED = 7


@njit(cache=True)
def recognize(raw, camera, prepare_settings, tracking, rotation, covariance, catalog, cell_density, finish):
    """
    Run the common path (module docstring) on RawSpots `raw` seen by the Pinhole `camera` around a prediction.

    tracking: (min_stars, max_pattern_spots, gate_sigma, max_gate_fov_radii,
    false_positive_bound, match_radius_px, pixel_scale [rad/px], half_diagonal [rad],
    grid_max_radius [rad], grid, magnitude_floor [mag]) (TrackingConfig, the identifier's and
    the camera's figures); rotation (sensor -> ICRS), covariance [rad^2]: the prediction;
    catalog: CatalogArrays; cell_density (C,) [1/sr] of its grid; finish: (min_fit_stars,
    unnameable (floor_px, density_px, gate_sigma, max_chance), fit_screen_chi2,
    outlier_sigma). Returns (verdict, prepared (PreparedSpots), gate [px], the verdict's count
    (spots, stars near, pairs, verified), squared offset from the prediction [sigma^2], fp,
    the verified matches (spot, star) and attitude, the published guide matches (spot, star),
    guide stars too uncertain (count), their fit (rotation, covariance, loss, residual), and
    for VOTE_IN_PYTHON the catalog stars in view (indices, u, v [px]: from_pairs goes on from
    them), then the verification radius [px]). Entries past what the verdict needs are
    placeholders.
    """
    (min_stars, max_pattern_spots, gate_sigma, max_gate_fov_radii, fp_limit, match_radius_px, pixel_scale,
     half_diagonal, grid_max_radius, grid, magnitude_floor) = tracking
    prepared = prepare_spots(raw, camera, prepare_settings)
    n = prepared.order.size
    empty_i = np.zeros(0, np.int64)
    empty = np.zeros(0)
    eye = np.eye(3)
    # The verification radius (StarIdentifier.verification_radius_px) and the gate (Tracker.gate_px).
    tolerance_px = verification_radius_px(prepared.sigma, pixel_scale, match_radius_px)
    cross = math.sqrt(max(covariance[0, 0], covariance[1, 1], 0.0))
    roll = math.sqrt(max(covariance[2, 2], 0.0)) * half_diagonal
    cap = max_gate_fov_radii * half_diagonal / pixel_scale
    gate = min(gate_sigma * (math.hypot(cross, roll) / pixel_scale) + tolerance_px, cap)
    if n < min_stars:
        return (TOO_FEW_SPOTS, prepared, gate, n, 0.0, 1.0, empty_i, empty_i, eye, empty_i, empty_i, 0, eye, eye,
                0.0, empty, empty_i, empty, empty, tolerance_px)
    reach = half_diagonal + gate * pixel_scale
    near, u, v = stars_in_view(catalog.vectors, rotation, math.cos(min(reach, math.pi / 2)), camera, -gate)
    if near.size < min_stars:
        return (TOO_FEW_STARS_NEAR, prepared, gate, near.size, 0.0, 1.0, empty_i, empty_i, eye, empty_i, empty_i, 0,
                eye, eye, 0.0, empty, empty_i, empty, empty, tolerance_px)
    if gate > 3.0 * tolerance_px:  # the displacement is voted (Tracker.track, vote_displacement): in view so far
        return (VOTE_IN_PYTHON, prepared, gate, near.size, 0.0, 1.0, empty_i, empty_i, eye, empty_i, empty_i, 0, eye,
                eye, 0.0, empty, near, u, v, tolerance_px)
    return from_pairs(prepared, gate, tolerance_px, near, u, v, 0.0, 0.0, gate, tracking, rotation, covariance, catalog,
                      cell_density, finish)


@njit(cache=True)
def from_pairs(prepared, gate, tolerance_px, near, u, v, dx, dy, radius, tracking, rotation, covariance, catalog,
               cell_density, finish):
    """
    Go on from the catalog stars in view: (near, u, v [px]) from stars_in_view, moved by (dx, dy) [px].

    The nearest pairs within `radius` [px], their attitude, the verification, the bound and
    the published fit; arguments and result as recognize's (prepared: the spots; gate and
    tolerance_px [px]: the frame's gate and verification radius).
    """
    (min_stars, max_pattern_spots, gate_sigma, max_gate_fov_radii, fp_limit, match_radius_px, pixel_scale,
     half_diagonal, grid_max_radius, grid, magnitude_floor) = tracking
    min_fit_stars, unnameable, screen_chi2, outlier_sigma = finish
    n = prepared.order.size
    empty_i = np.zeros(0, np.int64)
    empty = np.zeros(0)
    eye = np.eye(3)
    voters = min(n, max_pattern_spots)
    spot_i, star_j = unique_nearest(prepared.x[:voters], prepared.y[:voters], u + dx, v + dy, radius)
    if spot_i.size < 2:
        return (TOO_FEW_PAIRS, prepared, gate, spot_i.size, 0.0, 1.0, empty_i, empty_i, eye, empty_i, empty_i, 0, eye,
                eye, 0.0, empty, empty_i, empty, empty, tolerance_px)
    body = np.empty((spot_i.size, 3))
    ref = np.empty((spot_i.size, 3))
    weights = np.empty(spot_i.size)
    for q in range(spot_i.size):
        body[q] = prepared.rays[spot_i[q]]
        ref[q] = catalog.vectors[near[star_j[q]]]
        weights[q] = 1.0 / prepared.sigma[spot_i[q]] ** 2
    rough = q_method(body, ref, weights)
    # Tracker._verify_in_region.
    chord = 2.0 * math.sin(0.5 * min(tolerance_px * pixel_scale, grid_max_radius))
    out_spot = np.empty(n, np.int64)
    out_star = np.empty(n, np.int64)
    check = verify_candidate(rough, SpotArrays(prepared.rays, prepared.sigma, prepared.magnitude), catalog,
                             VerifySettings(chord, min_stars, magnitude_floor), out_spot, out_star, 1)
    count, verified = check.count, check.rotation
    if count < min_stars:
        return (TOO_FEW_VERIFIED, prepared, gate, count, 0.0, 1.0, empty_i, empty_i, eye, empty_i, empty_i, 0, eye,
                eye, 0.0, empty, empty_i, empty, empty, tolerance_px)
    mahalanobis2 = offset_mahalanobis2(rotation, verified, covariance)
    if mahalanobis2 > gate_sigma ** 2:
        return (OUTSIDE_GATE, prepared, gate, count, mahalanobis2, 1.0, empty_i, empty_i, eye, empty_i, empty_i, 0,
                eye, eye, 0.0, empty, empty_i, empty, empty, tolerance_px)
    spot = out_spot[:count].copy()
    star = out_star[:count].copy()
    matched = np.empty((count, 3))
    sigma = np.empty(count)
    spot_magnitude = np.empty(count)
    star_magnitude = np.empty(count)
    for q in range(count):
        matched[q] = prepared.rays[spot[q]]
        sigma[q] = prepared.sigma[spot[q]]
        spot_magnitude[q] = prepared.magnitude[spot[q]]
        star_magnitude[q] = catalog.magnitude[star[q]]
    density = max(catalog.mean_density,
                  cell_density[cell_of(verified[0, 2], verified[1, 2], verified[2, 2], grid)])
    log_t = log_chance_tuples_in_region(matched, sigma, check.chi2, density, covariance, gate_sigma)
    log_t += log_magnitude_agreement(spot_magnitude, star_magnitude, catalog.sorted_magnitudes, magnitude_floor)
    fp = false_positive_bound(log_t, n, count, min_stars)
    if fp > fp_limit:
        return (BOUND_FAILED, prepared, gate, count, mahalanobis2, fp, spot, star, verified, empty_i, empty_i, 0, eye,
                eye, 0.0, empty, empty_i, empty, empty, tolerance_px)
    # StarIdentifier.solved for a tracked frame (no deep re-match).
    guide_spot, guide_star, too_uncertain, _, fitted, fitted_covariance, loss, residual = guide_fit(
        prepared, spot, star, catalog.vectors, verified, pixel_scale, unnameable, screen_chi2, min_fit_stars)
    if any_beyond(residual, prepared.sigma, guide_spot, outlier_sigma):
        return (NAME_IN_PYTHON, prepared, gate, count, mahalanobis2, fp, spot, star, verified, empty_i, empty_i, 0,
                eye, eye, 0.0, empty, empty_i, empty, empty, tolerance_px)
    return (SOLVED, prepared, gate, count, mahalanobis2, fp, spot, star, verified, guide_spot, guide_star,
            too_uncertain, fitted, fitted_covariance, loss, residual, empty_i, empty, empty,
            tolerance_px)
