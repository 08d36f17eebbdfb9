# SPDX-License-Identifier: Apache-2.0
"""
The deep re-match, compiled: deep_rematch runs it whole in one call, for every camera.

Its rules and constants are deep_match's (its module docstring); deep_match.deep_rematch
builds the records and calls it. The view's deep stars come from one cone query of the deep
catalog's cell index (deep_catalog.cone_stars) shared by every pass whose boresight stays
within its margin (a farther one queries again), projected with the camera's Brown-Conrady
model (LensModel, as models.camera.CameraModel.project). Pixel positions [px], covariances
[px^2], distances in sigmas (Mahalanobis), rotations sensor -> ICRS, attitude covariances
[rad^2] in the sensor frame.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..models.attitude_estimation import refine_kernel
from .deep_catalog import cone_stars
from .kernel_records import DeepRematchOutcome
from .kernels import false_positive_bound, log_chance_tuples, log_magnitude_agreement


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


@njit(cache=True)
def offset_parts(spots, pixel_scale, floor_px):
    """
    Return the per-spot parts of each spot's offset covariance: own (N, 2, 2) [px^2], carry (N, 2, 3) [px/rad].

    A spot's offset from its star's predicted pixel has covariance own + carry P carry^T under
    the sensor-frame attitude covariance P (offset_covariance): own, the spot's covariance +
    floor_px^2 I (isotropic sigma / pixel_scale when it has none); carry, d pixel / d attitude
    error, J+ [b]x with J = d ray / d pixel. Computed once per frame.
    """
    rays = spots.rays
    n = rays.shape[0]
    own = np.zeros((n, 2, 2))
    carry = np.zeros((n, 2, 3))
    isotropic = spots.pixel_cov.shape[0] == 0
    for i in range(n):
        if isotropic:
            s = spots.sigma[i] / pixel_scale
            own[i, 0, 0] = own[i, 1, 1] = s * s
        else:
            own[i, 0, 0] = spots.pixel_cov[i, 0, 0] + floor_px * floor_px
            own[i, 0, 1] = spots.pixel_cov[i, 0, 1]
            own[i, 1, 0] = spots.pixel_cov[i, 1, 0]
            own[i, 1, 1] = spots.pixel_cov[i, 1, 1] + floor_px * floor_px
        bx, by, bz = rays[i, 0], rays[i, 1], rays[i, 2]
        skew = np.array([[0.0, -bz, by], [bz, 0.0, -bx], [-by, bx, 0.0]])
        pinv = np.zeros((2, 3))
        if isotropic or spots.jacobian.shape[0] == 0:
            pinv[0, 0] = pinv[1, 1] = 1.0 / pixel_scale
        else:
            jac = spots.jacobian[i]  # (3, 2)
            g00 = g01 = g10 = g11 = 0.0
            for r in range(3):
                g00 += jac[r, 0] * jac[r, 0]
                g01 += jac[r, 0] * jac[r, 1]
                g10 += jac[r, 1] * jac[r, 0]
                g11 += jac[r, 1] * jac[r, 1]
            det = g00 * g11 - g01 * g10
            for r in range(3):
                pinv[0, r] = (g11 * jac[r, 0] - g01 * jac[r, 1]) / det
                pinv[1, r] = (-g10 * jac[r, 0] + g00 * jac[r, 1]) / det
        for a in range(2):
            for c in range(3):
                total = 0.0
                for r in range(3):
                    total += pinv[a, r] * skew[r, c]
                carry[i, a, c] = total
    return own, carry


@njit(cache=True)
def offset_covariance(own, carry, attitude_covariance, scale):
    """Return scale x (own + carry P carry^T): each spot's offset covariance (N, 2, 2) [px^2] under P [rad^2]."""
    n = own.shape[0]
    out = np.empty((n, 2, 2))
    for i in range(n):
        for a in range(2):
            for b in range(2):
                total = 0.0
                for r in range(3):
                    row = 0.0
                    for c in range(3):
                        row += attitude_covariance[r, c] * carry[i, b, c]
                    total += carry[i, a, r] * row
                out[i, a, b] = scale * (own[i, a, b] + total)
    return out


@njit(cache=True)
def pixel_of(x, y, z, lens):
    """
    Pixel (u, v) [px] of the sensor-frame direction (x, y, z) and whether the camera images it.

    models.camera.CameraModel.project for one ray: in front (z > 1e-9; behind, u and v are
    those of z = 1) and, with distortion, within lens.max_radius2 (beyond it the polynomial
    folds directions back into the image). In the image or not is the caller's question.
    """
    imaged = z > 1e-9
    if not imaged:
        z = 1.0
    x, y = x / z, y / z
    if lens.distorted:
        r2 = x * x + y * y
        imaged = imaged and r2 <= lens.max_radius2
        radial = 1.0 + r2 * (lens.k1 + r2 * (lens.k2 + r2 * lens.k3))
        x, y = (x * radial + 2.0 * lens.p1 * x * y + lens.p2 * (r2 + 2.0 * x * x),
                y * radial + lens.p1 * (r2 + 2.0 * y * y) + 2.0 * lens.p2 * x * y)
    pin = lens.pinhole
    return pin.fx * x + pin.cx, pin.fy * y + pin.cy, imaged


@njit(cache=True)
def _sensor(vector, rotation):
    """Return the ICRS unit vector in the sensor frame (rotation^T vector)."""
    return (vector[0] * rotation[0, 0] + vector[1] * rotation[1, 0] + vector[2] * rotation[2, 0],
            vector[0] * rotation[0, 1] + vector[1] * rotation[1, 1] + vector[2] * rotation[2, 1],
            vector[0] * rotation[0, 2] + vector[1] * rotation[1, 2] + vector[2] * rotation[2, 2])


@njit(cache=True)
def view_stars(deep, cone, rotation, lens, view_chord):
    """
    Return the `cone`'s deep stars imaged inside the image at `rotation`: catalog indices, u, v [px].

    Those within view_chord of the boresight, projected (pixel_of) inside the pixel area.
    """
    m = cone.size
    star = np.empty(m, np.int64)
    us = np.empty(m)
    vs = np.empty(m)
    count = 0
    bx, by, bz = rotation[0, 2], rotation[1, 2], rotation[2, 2]
    chord2 = view_chord * view_chord
    for q in range(m):
        s = cone[q]
        dx, dy, dz = deep.vectors[s, 0] - bx, deep.vectors[s, 1] - by, deep.vectors[s, 2] - bz
        if dx * dx + dy * dy + dz * dz > chord2:
            continue
        x, y, z = _sensor(deep.vectors[s], rotation)
        u, v, imaged = pixel_of(x, y, z, lens)
        if imaged and -0.5 <= u <= lens.pinhole.width - 0.5 and -0.5 <= v <= lens.pinhole.height - 0.5:
            star[count], us[count], vs[count] = s, u, v
            count += 1
    return star[:count], us[:count], vs[:count]


@njit(cache=True)
def magnitude_fraction(sorted_magnitudes, center, half_width):
    """
    Return the share of catalog stars within half_width [mag] of center [mag] (sorted_magnitudes: the catalog's).

    Under chance (a star unrelated to the spot, its magnitude drawn from the catalog's), the
    share of stars at least as close in brightness: uniform on [0, 1].
    """
    count = max(sorted_magnitudes.size, 1)
    out = np.empty(center.size)
    for q in range(center.size):
        low = np.searchsorted(sorted_magnitudes, center[q] - half_width[q], side="left")
        high = np.searchsorted(sorted_magnitudes, center[q] + half_width[q], side="right")
        out[q] = (high - low) / count
    return out


@njit(cache=True)
def chance_pairs(near_stars, fraction, gate_stars):
    """
    Return the expected number of unrelated deep stars in a spot's gate as good as its candidate.

    near_stars: the expected unrelated stars nearer than the candidate (density x its Mahalanobis
    ellipse's area); fraction: the share as close in brightness (magnitude_fraction; NaN when
    unknown: geometry alone); gate_stars: those expected in the whole gate. Unrelated stars
    fall uniformly in the image (expected count `a` up to gate_stars) with a brightness share
    `b` uniform on [0, 1]; the expected number with a b <= t = near_stars x fraction is
    t (1 + ln(gate_stars / t)), or near_stars alone without magnitudes.
    """
    out = np.empty(near_stars.size)
    for q in range(near_stars.size):
        t = near_stars[q] * fraction[q]
        if not np.isfinite(t):
            out[q] = near_stars[q]
        elif t > 0.0:
            out[q] = t * (1.0 + math.log(max(gate_stars[q] / t, 1.0)))
        else:
            out[q] = 0.0
    return out


@njit(cache=True)
def magnitude_zero_point(spot_magnitude, star_magnitude, min_stars, sigmas, floor):
    """
    Return (known, zero point, tolerance) [mag] from the guide matches' instrumental and catalog magnitudes.

    The zero point: the median difference; the tolerance: `sigmas` robust sigmas of their
    scatter, at least `floor`; not known with fewer than min_stars finite differences.
    """
    diff = np.empty(spot_magnitude.size)
    count = 0
    for i in range(spot_magnitude.size):
        d = spot_magnitude[i] - star_magnitude[i]
        if np.isfinite(d):
            diff[count] = d
            count += 1
    if count < min_stars:
        return False, 0.0, 0.0
    zero = np.median(diff[:count])
    spread = np.empty(count)
    for i in range(count):
        spread[i] = abs(diff[i] - zero)
    robust_sigma = 1.4826 * np.median(spread)
    return True, zero, max(sigmas * robust_sigma, floor)


@njit(cache=True)
def match_view(spots, deep, star, u, v, cov, guide_spot, guide_hip_sorted, guide_magnitude, max_chance, settings):
    """
    Return the unambiguous deep pairs of the spots without a guide star, on the view's deep stars (view_stars).

    star, u, v: the view's stars and pixels; cov (N, 2, 2) [px^2] the spots' offset covariances
    (offset_covariance); guide_spot, guide_hip_sorted, guide_magnitude: the guide matches (the
    zero point; their stars are taken); max_chance: the frame's chance bound (inf: the
    candidates every other condition passes). Returns (spot, star, chance, stars_in_view,
    ambiguous, magnitude_rejected, too_uncertain, chance_rejected, uncatalogued): spot (K,)
    increasing, star (K,) deep catalog indices.
    """
    n, m = spots.x.size, star.size
    density_px = m / settings.image_area
    gate2 = settings.gate_sigma * settings.gate_sigma
    det = np.empty(n)
    narrow = np.empty(n, np.bool_)
    free = np.ones(n, np.bool_)
    free[guide_spot] = False
    too_uncertain = 0
    for i in range(n):
        det[i] = cov[i, 0, 0] * cov[i, 1, 1] - cov[i, 0, 1] * cov[i, 1, 0]
        narrow[i] = density_px * np.pi * gate2 * math.sqrt(max(det[i], 0.0)) <= settings.max_chance_stars_in_gate
        if free[i] and not narrow[i]:
            too_uncertain += 1
        free[i] = free[i] and narrow[i]
    spot_i, star_j, d2, ambiguous, uncatalogued = deep_pairs(
        spots.x, spots.y, cov, narrow, free, u, v, deep.hip[star], guide_hip_sorted,
        settings.ambiguity_factor * settings.gate_sigma, settings.gate_sigma)
    k = spot_i.size
    star_k = star[star_j]
    fraction = np.full(k, np.nan)  # share of deep stars as close in brightness (NaN: unknown)
    keep = np.ones(k, np.bool_)
    rejected = 0
    if k:
        known, zero, tolerance = magnitude_zero_point(spots.magnitude[guide_spot], guide_magnitude,
                                                      settings.min_zero_point_stars, settings.magnitude_sigma,
                                                      settings.magnitude_tolerance_floor)
        if known:
            residual = np.empty(k)
            for q in range(k):
                residual[q] = spots.magnitude[spot_i[q]] - zero - deep.magnitude[star_k[q]]
                if abs(residual[q]) > tolerance:  # an unknown (NaN) spot magnitude passes on geometry
                    keep[q] = False
                    rejected += 1
            fraction = magnitude_fraction(deep.sorted_magnitudes, deep.magnitude[star_k] + residual,
                                          np.abs(residual))
            for q in range(k):
                if not np.isfinite(residual[q]):
                    fraction[q] = np.nan
    gate_stars = np.empty(k)
    near = np.empty(k)
    for q in range(k):
        gate_stars[q] = density_px * np.pi * gate2 * math.sqrt(max(det[spot_i[q]], 0.0))
        near[q] = gate_stars[q] * d2[q] / gate2
    chance = chance_pairs(near, fraction, gate_stars)
    # The uncatalogued spots (false objects, stars beyond the catalog): those tried without a
    # deep star within reach (an uncatalogued spot has one with probability < 4 x
    # max_chance_stars_in_gate), at least one.
    uncatalogued = max(uncatalogued, 1)
    out_spot = np.empty(k, np.int64)
    out_star = np.empty(k, np.int64)
    out_chance = np.empty(k)
    named = chance_rejected = 0
    for q in range(k):
        if not keep[q]:
            continue
        if chance[q] * uncatalogued <= max_chance:
            out_spot[named], out_star[named], out_chance[named] = spot_i[q], star_k[q], chance[q]
            named += 1
        else:
            chance_rejected += 1
    return (out_spot[:named], out_star[:named], out_chance[:named], m, ambiguous, rejected, too_uncertain,
            chance_rejected, uncatalogued)


@njit(cache=True)
def error_scale(spots, guide_spot, guide_vectors, rotation, cov, lens, min_stars, median_chi2):
    """
    Return the match gate's variance scale (>= 1).

    The median squared Mahalanobis offset of the guide matches (guide_spot, their ICRS
    guide_vectors) from their stars projected at `rotation`, under the offset covariances cov
    (N, 2, 2) [px^2] of all spots, over its expectation for a 2-D Gaussian, median_chi2 (robust
    to a few outliers); 1 with fewer than min_stars known.
    """
    g = guide_spot.size
    d2 = np.empty(g)
    count = 0
    for q in range(g):
        x, y, z = _sensor(guide_vectors[q], rotation)
        u, v, _ = pixel_of(x, y, z, lens)
        i = guide_spot[q]
        dx, dy = spots.x[i] - u, spots.y[i] - v
        a, c = cov[i, 0, 0], cov[i, 1, 1]
        b = 0.5 * (cov[i, 0, 1] + cov[i, 1, 0])
        value = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / (a * c - b * b)
        if np.isfinite(value):
            d2[count] = value
            count += 1
    if count < min_stars:
        return 1.0
    return max(1.0, np.median(d2[:count]) / median_chi2)


@njit(cache=True)
def fit_matches(spots, spot_index, star_vectors, rotation, screen_chi2, min_stars):
    """
    base.StarIdentifier._fit: the published attitude of the matches, their outliers screened once.

    Returns (rotation, covariance [rad^2], loss, residual angles (M,) [rad]).
    """
    m = spot_index.size
    body = np.empty((m, 3))
    for q in range(m):
        body[q] = spots.rays[spot_index[q]]
    if spots.pixel_cov.shape[0] == 0:  # isotropic
        cov = np.empty((m, 3, 3))
        for q in range(m):
            s2 = spots.sigma[spot_index[q]] ** 2
            for r in range(3):
                for c in range(3):
                    cov[q, r, c] = s2 * ((1.0 if r == c else 0.0) - body[q, r] * body[q, c])
        jac = np.zeros((0, 3, 2))
    else:
        cov = np.empty((m, 2, 2))
        jac = np.empty((m, 3, 2))
        for q in range(m):
            cov[q] = spots.pixel_cov[spot_index[q]]
            jac[q] = spots.jacobian[spot_index[q]]
    used = np.ones(m, np.bool_)
    rotation, covariance, loss, chi2, angle = refine_kernel(rotation, body, star_vectors, cov, jac, used, 2)
    inlier = chi2 <= screen_chi2
    if not inlier.all() and inlier.sum() >= min_stars:
        rotation, covariance, loss, chi2, angle = refine_kernel(rotation, body, star_vectors, cov, jac, inlier, 2)
    return np.ascontiguousarray(rotation), np.ascontiguousarray(covariance), loss, angle


@njit(cache=True)
def bound(spots, spot_index, star_vectors, star_magnitude, rotation, stars_in_view, deep, settings):
    """
    Return the false-positive bound of verify.py over the matches at `rotation`.

    The matches: spot_index into the spots, their ICRS star_vectors and catalog magnitudes;
    with the deep catalog's density (the larger of its mean and its density in this view,
    stars_in_view) and magnitude distribution; the matching sigmas as in verification. Matches
    beyond 5 sigma count for nothing (left out, as verification leaves them out).
    """
    m = spot_index.size
    keep = np.empty(m, np.int64)
    kept = 0
    chi2 = 0.0
    normalized = np.empty(m)
    for q in range(m):
        i = spot_index[q]
        total = 0.0
        for a in range(3):
            pred = star_vectors[q, 0] * rotation[0, a] + star_vectors[q, 1] * rotation[1, a] \
                + star_vectors[q, 2] * rotation[2, a]
            total += (spots.rays[i, a] - pred) ** 2
        normalized[q] = math.sqrt(total) / spots.sigma[i]
        if normalized[q] <= 5.0:
            keep[kept] = q
            kept += 1
    if kept < settings.min_stars:
        return 1.0
    body = np.empty((kept, 3))
    sigma = np.empty(kept)
    spot_mag = np.empty(kept)
    star_mag = np.empty(kept)
    for r in range(kept):
        q = keep[r]
        body[r] = spots.rays[spot_index[q]]
        sigma[r] = spots.sigma[spot_index[q]]
        spot_mag[r] = spots.magnitude[spot_index[q]]
        star_mag[r] = star_magnitude[q]
        chi2 += normalized[q] ** 2
    density = max(settings.mean_density, stars_in_view / (settings.image_area * settings.pixel_scale ** 2))
    log_t = log_chance_tuples(body, sigma, chi2, density)
    log_t += log_magnitude_agreement(spot_mag, star_mag, deep.sorted_magnitudes, settings.magnitude_floor)
    return false_positive_bound(log_t, spots.x.size, kept, settings.min_stars)


@njit(cache=True)
def _same(a_spot, a_star, b_spot, b_star):
    if a_spot.size != b_spot.size:
        return False
    for q in range(a_spot.size):
        if a_spot[q] != b_spot[q] or a_star[q] != b_star[q]:
            return False
    return True


@njit(cache=True)
def _extended(guide_spot, guide_vectors, guide_magnitude, deep, spot, star):
    """Return the guide matches followed by deep ones: spot indices, ICRS vectors, catalog magnitudes."""
    g, k = guide_spot.size, spot.size
    spot_index = np.empty(g + k, np.int64)
    vectors = np.empty((g + k, 3))
    magnitude = np.empty(g + k)
    spot_index[:g] = guide_spot
    vectors[:g] = guide_vectors
    magnitude[:g] = guide_magnitude
    for q in range(k):
        spot_index[g + q] = spot[q]
        vectors[g + q] = deep.vectors[star[q]]
        magnitude[g + q] = deep.magnitude[star[q]]
    return spot_index, vectors, magnitude


@njit(cache=True)
def deep_rematch(spots, deep, cells, guide, rotation, covariance, lens, settings):
    """
    base.StarIdentifier.deep_rematch in one call (see its docstring and deep_match's).

    spots: PreparedSpots (pixel_cov and jacobian (0, ...) when isotropic; order unused);
    deep: DeepArrays; cells: the deep catalog's CellIndex; guide: GuideMatches; rotation
    (sensor -> ICRS), covariance [rad^2]: the guide fit; lens: LensModel. Returns a
    DeepRematchOutcome: status 1 with the deep matches (spot, star), the fitted rotation,
    covariance, loss, residual angles of guide then deep matches and their bound; 0 when the
    guide solution stands.
    """
    stats = np.zeros(8, np.int64)  # matches, ambiguous, magnitude, uncertain, in view, candidates, chance, bound
    empty_i = np.zeros(0, np.int64)
    none = DeepRematchOutcome(0, empty_i, empty_i, rotation, covariance, 0.0, np.zeros(0), 1.0, stats)
    guide_hip_sorted = np.sort(guide.hip)
    axis = rotation[:, 2].copy()
    cone = cone_stars(deep.vectors, cells.cell_start, cells.star_of_cell, cells.centres, cells.reach, axis,
                      settings.cone_chord)
    own, carry = offset_parts(spots, settings.pixel_scale, settings.floor_px)
    cov = offset_covariance(own, carry, covariance, 1.0)
    scale = error_scale(spots, guide.spot, guide.vectors, rotation, cov, lens, settings.min_stars,
                        settings.median_chi2_2dof)
    fitted, fitted_cov, loss = rotation, covariance, 0.0
    residual = np.zeros(0)
    match_spot, match_vectors, match_magnitude = guide.spot, guide.vectors, guide.magnitude
    found = (empty_i, empty_i, np.zeros(0), 0, 0, 0, 0, 0, 1)
    latest = found
    at_fitted = False  # `latest` holds the candidates at `fitted` itself
    for round_index in range(settings.passes):
        cov = offset_covariance(own, carry, fitted_cov if round_index else covariance, scale)
        if not _within(fitted, axis, settings.margin_chord):  # the refit moved far: query its own cone
            axis = fitted[:, 2].copy()
            cone = cone_stars(deep.vectors, cells.cell_start, cells.star_of_cell, cells.centres, cells.reach, axis,
                              settings.cone_chord)
        star, u, v = view_stars(deep, cone, fitted, lens, settings.view_chord)
        latest = match_view(spots, deep, star, u, v, cov, guide.spot, guide_hip_sorted, guide.magnitude, np.inf,
                            settings)
        if round_index and _same(latest[0], latest[1], found[0], found[1]):
            at_fitted = True
            break
        found = latest
        if found[0].size == 0:
            break
        match_spot, match_vectors, match_magnitude = _extended(guide.spot, guide.vectors, guide.magnitude, deep,
                                                               found[0], found[1])
        fitted, fitted_cov, loss, residual = fit_matches(spots, match_spot, match_vectors, fitted,
                                                         settings.fit_screen_chi2, settings.min_stars)
    stats[0], stats[1], stats[2], stats[3], stats[4] = found[0].size, found[4], found[5], found[6], found[3]
    if found[0].size == 0:
        return none
    if bound(spots, match_spot, match_vectors, match_magnitude, fitted, found[3], deep, settings) > settings.fp_limit:
        stats[0], stats[7] = 0, 1
        return none
    # Name only the pairs unlikely by chance, at the attitude the candidates refined.
    if at_fitted:  # the last pass matched at this attitude and covariance already
        keep = latest[2] * latest[8] <= settings.max_chance_matches
        named_spot, named_star = latest[0][keep], latest[1][keep]
        chance_rejected = latest[7] + int(np.count_nonzero(~keep))
        in_view = latest[3]
    else:
        if not _within(fitted, axis, settings.margin_chord):
            axis = fitted[:, 2].copy()
            cone = cone_stars(deep.vectors, cells.cell_start, cells.star_of_cell, cells.centres, cells.reach, axis,
                              settings.cone_chord)
        star, u, v = view_stars(deep, cone, fitted, lens, settings.view_chord)
        named = match_view(spots, deep, star, u, v, offset_covariance(own, carry, fitted_cov, scale), guide.spot,
                           guide_hip_sorted, guide.magnitude, settings.max_chance_matches, settings)
        named_spot, named_star, chance_rejected, in_view = named[0], named[1], named[7], named[3]
    stats[0], stats[5], stats[6] = named_spot.size, found[0].size, chance_rejected
    if named_spot.size == 0:
        return none
    match_spot, match_vectors, match_magnitude = _extended(guide.spot, guide.vectors, guide.magnitude, deep,
                                                           named_spot, named_star)
    fitted, fitted_cov, loss, residual = fit_matches(spots, match_spot, match_vectors, fitted,
                                                     settings.fit_screen_chi2, settings.min_stars)
    fp = bound(spots, match_spot, match_vectors, match_magnitude, fitted, in_view, deep, settings)
    if fp > settings.fp_limit:
        stats[0], stats[7] = 0, 1
        return none
    return DeepRematchOutcome(1, named_spot, named_star, fitted, fitted_cov, loss, residual, fp, stats)


@njit(cache=True)
def _within(rotation, axis, chord):
    """Whether the boresight of `rotation` lies within `chord` of the unit vector `axis`."""
    gap = 0.0
    for a in range(3):
        gap += (rotation[a, 2] - axis[a]) ** 2
    return gap <= chord * chord
