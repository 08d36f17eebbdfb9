# SPDX-License-Identifier: Apache-2.0
"""
A lost-in-space solve in one compiled call: the hybrid identifier's common path, from the spots to the published fit.

What base.StarIdentifier.identify does with hybrid's search, for a camera without distortion,
as long as no rare branch is taken: prepare the spots (spot_kernels.prepare_spots), try the
first batch of pyramid triangles (kernels.search_triangles), check the accepted match for a
lever-arm outlier (its fit's chi^2 only), leave out the guide stars too uncertain to name, fit
the published attitude, run the deep re-match (deep_match_kernel.deep_rematch) and check that
no guide star lies beyond FIT_OUTLIER_SIGMA of the result. Every step calls the kernel the
Python path calls, with the same arguments, so the result is the same to the bit
(test_solve_kernel). When the first batch finds no match, or the lever-arm check or the last
check fails, the call says so and the Python path takes over from there (hybrid.py): the
rare branches (another batch under the time budget, the lever-arm examination, naming the
guide stars again) live in one place only.

On the nominal scenes this replaces some forty Python-level steps around the kernels, which
took about half of the lost-in-space time (docs/BENCHMARKS.md § Profiles).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .deep_match_kernel import deep_rematch
from .final_fit_kernel import any_beyond, guide_fit, match_chi2, verification_radius_px
from .geometry import pyramid_rows
from .kernel_records import DeepRematchOutcome, GuideMatches, SearchScratch, SpotArrays, VerifySettings
from .kernels import search_triangles
from .spot_kernels import prepare_spots

# solve's verdicts.
TOO_FEW_SPOTS = 0  # fewer than min_stars usable spots
NOT_FOUND = 1  # the first batch of triangles verified nothing: the search goes on (in Python, under the budget)
FINISH_IN_PYTHON = 2  # a match, but the lever-arm examination or the guide stars' naming again is needed
SOLVED = 3  # the published solution is in the result


@njit(cache=True)
def solve(raw, camera, prepare_settings, search, pairs, catalog, tolerances, heads, finish, deep, cells, lens,
          deep_settings):
    """
    Run the common path (module docstring) on RawSpots `raw` seen by the Pinhole `camera`.

    search: (max_pattern_spots, first_batch, match_radius_px, pixel_scale [rad/px],
    grid_max_radius [rad], min_stars, magnitude_floor [mag]); heads: (head_ik, head_jk) the
    search scratch (all -1); finish: (lever_limits (D,) chi^2 limits by degrees of freedom,
    guide vectors (S, 3), guide hip (S,), guide magnitude (S,), unnameable (floor_px,
    density_px, gate_sigma, max_chance), fit_screen_chi2, outlier_sigma); deep, cells, lens,
    deep_settings: the deep re-match's records. Returns (verdict, prepared (PreparedSpots),
    hypotheses, triangles tried, the accepted match (spot, star, rotation, fp), the guide
    matches published (spot, star), guide stars too uncertain (count), the guide fit (rotation,
    covariance, loss, residual), whether the deep re-match ran, its outcome); the entries after
    the verdict's are placeholders.
    """
    max_pattern_spots, first_batch, match_radius_px, pixel_scale, grid_max_radius, min_stars, magnitude_floor = search
    lever_limits, vectors, hip, magnitude, unnameable, screen_chi2, outlier_sigma = finish
    prepared = prepare_spots(raw, camera, prepare_settings)
    n = prepared.order.size
    empty_i = np.zeros(0, np.int64)
    eye = np.eye(3)
    nothing = DeepRematchOutcome(0, empty_i, empty_i, eye, eye, 0.0, np.zeros(0), 1.0, np.zeros(8, np.int64))
    if n < min_stars:
        return (TOO_FEW_SPOTS, prepared, 0, 0, empty_i, empty_i, eye, 1.0, empty_i, empty_i, 0, eye, eye, 0.0,
                np.zeros(0), False, nothing)
    pattern_count = min(n, max_pattern_spots)
    radius_rad = min(verification_radius_px(prepared.sigma, pixel_scale, match_radius_px) * pixel_scale,
                     grid_max_radius)
    verification = VerifySettings(2.0 * math.sin(0.5 * radius_rad), min_stars, magnitude_floor)
    spots = SpotArrays(prepared.rays, prepared.sigma, prepared.magnitude)
    scratch = SearchScratch(heads[0], heads[1], np.empty(n, np.int64), np.empty(n, np.int64))
    triangles = pyramid_rows(pattern_count, first_batch)
    found = search_triangles(triangles, 0, triangles.shape[0], spots, pairs, catalog, tolerances, verification,
                             scratch, pattern_count)
    if found.status != 1:
        return (NOT_FOUND, prepared, found.hypotheses, found.stopped, empty_i, empty_i, eye, 1.0, empty_i, empty_i,
                0, eye, eye, 0.0, np.zeros(0), False, nothing)
    spot = scratch.out_spot[:found.count].copy()
    star = scratch.out_star[:found.count].copy()
    # The lever-arm check (StarIdentifier.without_lever_outlier): its examination is Python's.
    count = spot.size
    if count > min_stars:
        dof = 2 * count - 3
        if dof >= lever_limits.size or match_chi2(prepared.rays, prepared.sigma, vectors, spot, star,
                                                  found.rotation) > lever_limits[dof]:
            return (FINISH_IN_PYTHON, prepared, found.hypotheses, found.stopped, spot, star, found.rotation, found.fp,
                    empty_i, empty_i, 0, eye, eye, 0.0, np.zeros(0), False, nothing)
    guide_spot, guide_star, too_uncertain, guide_vectors, fitted, covariance, loss, residual = guide_fit(
        prepared, spot, star, vectors, found.rotation, pixel_scale, unnameable, screen_chi2, min_stars)
    ran_deep = guide_spot.size < n  # with every spot named there is nothing left to match
    outcome = nothing
    final_residual = residual
    if ran_deep:
        guide_hip = np.empty(guide_spot.size, np.int64)
        guide_magnitude = np.empty(guide_spot.size)
        for i in range(guide_spot.size):
            guide_hip[i] = hip[guide_star[i]]
            guide_magnitude[i] = magnitude[guide_star[i]]
        outcome = deep_rematch(prepared, deep, cells, GuideMatches(guide_spot, guide_vectors, guide_hip,
                                                                   guide_magnitude),
                               fitted, covariance, lens, deep_settings)
        if outcome.status != 0:
            final_residual = outcome.residual
    # A guide star beyond outlier_sigma of the published attitude: named again in Python (StarIdentifier.solved).
    if any_beyond(final_residual, prepared.sigma, guide_spot, outlier_sigma):
        return (FINISH_IN_PYTHON, prepared, found.hypotheses, found.stopped, spot, star, found.rotation, found.fp,
                empty_i, empty_i, 0, eye, eye, 0.0, np.zeros(0), False, nothing)
    return (SOLVED, prepared, found.hypotheses, found.stopped, spot, star, found.rotation, found.fp, guide_spot,
            guide_star, too_uncertain, fitted, covariance, loss, residual, ran_deep, outcome)
