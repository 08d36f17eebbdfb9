# SPDX-License-Identifier: Apache-2.0
"""
Compiled pairing of the deep re-match (deep_match.match_deep): spots and projected deep stars.

One call finds every (spot, star) pair within the ambiguity reach, counts each spot's and
star's pairs, and returns the unambiguous pairs inside the gate, with the counts
match_deep reports. Pixel positions [px], covariances [px^2], distances in sigmas
(Mahalanobis); the conditions are deep_match's (its module docstring).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def deep_pairs(spot_x, spot_y, cov, claimant, free, star_u, star_v, star_hip, guide_hip, reach_sigma, gate_sigma):
    """
    Return (spot, star, d2, ambiguous, uncatalogued) of the unambiguous pairs inside the gate.

    spot_x, spot_y (N,) [px] and cov (N, 2, 2) [px^2] the spots' positions and offset
    covariances; claimant (N,) the spots whose gate is narrow enough to claim a star; free (N,)
    the claimants without a guide star (the ones to match); star_u, star_v (M,) [px] the view's
    deep stars projected, star_hip (M,) their HIP ids; guide_hip (G,) the guide matches' HIP ids,
    sorted (a star already named by a guide match is taken).

    A pair: a claimant and a star within reach_sigma (Mahalanobis, under the spot's cov). A
    pair is returned when its spot is free, it lies within gate_sigma, and neither its spot nor
    its star has another pair, and its star is not taken: spot (K,) indices into the spots in
    increasing order, star (K,) indices into the view's stars, d2 (K,) squared Mahalanobis
    distances. ambiguous: the free spots with a pair inside the gate not returned; uncatalogued:
    the free spots with no pair at all.
    """
    n, m = spot_x.size, star_u.size
    order = np.argsort(star_u, kind="mergesort")
    sorted_u = star_u[order]
    reach2 = reach_sigma * reach_sigma
    gate2 = gate_sigma * gate_sigma
    spots_near_star = np.zeros(m, np.int64)
    stars_near_spot = np.zeros(n, np.int64)
    # A spot's pair, while it has exactly one: (star, d2).
    only_star = np.full(n, -1, np.int64)
    only_d2 = np.zeros(n)
    inside_any = np.zeros(n, np.bool_)
    for i in range(n):
        if not claimant[i]:
            continue
        a, c = cov[i, 0, 0], cov[i, 1, 1]
        b = 0.5 * (cov[i, 0, 1] + cov[i, 1, 0])
        radius = reach_sigma * math.sqrt(0.5 * (a + c) + math.sqrt(0.25 * (a - c) ** 2 + b * b))  # largest axis
        if not math.isfinite(radius):
            continue
        det = a * c - b * b
        first = np.searchsorted(sorted_u, spot_x[i] - radius, side="left")
        last = np.searchsorted(sorted_u, spot_x[i] + radius, side="right")
        for r in range(first, last):
            j = order[r]
            dx, dy = spot_x[i] - star_u[j], spot_y[i] - star_v[j]
            if dx * dx + dy * dy > radius * radius:
                continue
            d2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det  # offset^T cov^-1 offset
            if not d2 <= reach2:  # NaN (a degenerate covariance) is no pair
                continue
            stars_near_spot[i] += 1
            spots_near_star[j] += 1
            only_star[i], only_d2[i] = j, d2
            if d2 <= gate2:
                inside_any[i] = True
    out_spot = np.empty(n, np.int64)
    out_star = np.empty(n, np.int64)
    out_d2 = np.empty(n)
    k = ambiguous = uncatalogued = 0
    for i in range(n):
        if not free[i]:
            continue
        if stars_near_spot[i] == 0:
            uncatalogued += 1
            continue
        if not inside_any[i]:
            continue
        j = only_star[i]
        taken = False
        if stars_near_spot[i] == 1:
            g = np.searchsorted(guide_hip, star_hip[j])
            taken = g < guide_hip.size and guide_hip[g] == star_hip[j]
        if stars_near_spot[i] == 1 and spots_near_star[j] == 1 and not taken:
            out_spot[k], out_star[k], out_d2[k] = i, j, only_d2[i]
            k += 1
        else:
            ambiguous += 1
    return out_spot[:k], out_star[:k], out_d2[:k], ambiguous, uncatalogued
