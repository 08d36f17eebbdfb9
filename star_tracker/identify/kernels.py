# SPDX-License-Identifier: Apache-2.0
"""
Compiled identification kernels (numba).

Triangle search over the pair k-vector, the q-method, spot-to-star matching on the sky grid
and the false-positive bound of `verify`, in one call per batch of spot triangles so a frame
costs microseconds, not Python overhead. Spot preparation is in spot_kernels.py, tracking's
kernels in track/kernels.py.

The mathematics is the one documented in base.py and verify.py; these are its loops.
Kernels take their inputs as small records (kernel_records.py): the catalog, the spots, the
pair index, the tolerances.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .geometry import angle_between, triple_product_rows
from .kernel_records import CandidateCheck, TriangleSearchResult
from .skygrid import cell_of, cells_near

LN_8PI2 = math.log(8.0 * math.pi**2)
LN_PI = math.log(math.pi)


@njit(cache=True)
def kvector_range(values, k, slope, intercept, lo, hi):
    """[start, stop) of the sorted `values` inside [lo, hi] (see kvector.KVector.range)."""
    n = k.size
    if hi < lo or hi < values[0] or lo > values[n - 1]:
        return 0, 0
    j_lo = int(math.floor((lo - intercept) / slope))
    j_hi = int(math.ceil((hi - intercept) / slope))
    start = k[min(j_lo - 1, n - 1)] if j_lo >= 1 else 0
    stop = k[j_hi] if 0 <= j_hi < n else n
    while start < stop and values[start] < lo:
        start += 1
    while stop > start and values[stop - 1] > hi:
        stop -= 1
    return start, stop


@njit(cache=True)
def q_method(body, ref, weights):
    """Sensor -> ICRS rotation maximizing sum w |b - R^T r|^2 agreement (Davenport)."""
    b = np.zeros((3, 3))
    for i in range(body.shape[0]):
        for r in range(3):
            for c in range(3):
                b[r, c] += weights[i] * body[i, r] * ref[i, c]
    tr = b[0, 0] + b[1, 1] + b[2, 2]
    kmat = np.empty((4, 4))
    for r in range(3):
        for c in range(3):
            kmat[r, c] = b[r, c] + b[c, r] - (tr if r == c else 0.0)
    z0, z1, z2 = b[1, 2] - b[2, 1], b[2, 0] - b[0, 2], b[0, 1] - b[1, 0]
    kmat[0, 3] = kmat[3, 0] = z0
    kmat[1, 3] = kmat[3, 1] = z1
    kmat[2, 3] = kmat[3, 2] = z2
    kmat[3, 3] = tr
    _, vecs = np.linalg.eigh(kmat)
    x, y, z, w = vecs[0, 3], vecs[1, 3], vecs[2, 3], vecs[3, 3]
    # Shuster's A(q) maps ICRS -> sensor; the published rotation is its transpose.
    a = np.empty((3, 3))
    a[0, 0] = w * w + x * x - y * y - z * z
    a[0, 1] = 2 * (x * y + w * z)
    a[0, 2] = 2 * (x * z - w * y)
    a[1, 0] = 2 * (x * y - w * z)
    a[1, 1] = w * w - x * x + y * y - z * z
    a[1, 2] = 2 * (y * z + w * x)
    a[2, 0] = 2 * (x * z + w * y)
    a[2, 1] = 2 * (y * z - w * x)
    a[2, 2] = w * w - x * x - y * y + z * z
    return a.T.copy()


@njit(cache=True)
def triad(b1, b2, r1, r2):
    """
    Sensor -> ICRS rotation taking b1 exactly onto r1 and b2 into the r1-r2 plane (TRIAD).

    A cheap first attitude for screening candidates.
    """
    rot = np.zeros((3, 3))
    fb = np.empty((3, 3))
    fr = np.empty((3, 3))
    for src, dst1, dst2 in ((fb, b1, b2), (fr, r1, r2)):
        src[0] = dst1
        cx = dst1[1] * dst2[2] - dst1[2] * dst2[1]
        cy = dst1[2] * dst2[0] - dst1[0] * dst2[2]
        cz = dst1[0] * dst2[1] - dst1[1] * dst2[0]
        norm = math.sqrt(cx * cx + cy * cy + cz * cz)
        src[1, 0], src[1, 1], src[1, 2] = cx / norm, cy / norm, cz / norm
        src[2, 0] = src[0, 1] * src[1, 2] - src[0, 2] * src[1, 1]
        src[2, 1] = src[0, 2] * src[1, 0] - src[0, 0] * src[1, 2]
        src[2, 2] = src[0, 0] * src[1, 1] - src[0, 1] * src[1, 0]
    for r in range(3):
        for c in range(3):
            rot[r, c] = fr[0, r] * fb[0, c] + fr[1, r] * fb[1, c] + fr[2, r] * fb[2, c]
    return rot


@njit(cache=True)
def nearest_star(rotation, ray, chord, catalog, cells):
    """
    Find the catalog star (CatalogArrays) nearest to the sensor-frame `ray` rotated to ICRS.

    If within `chord` (2 sin(radius/2)): (star index or -1, dot product). `cells`: scratch of
    4.
    """
    vectors, cell_start, star_of_cell, grid = catalog.vectors, catalog.cell_start, catalog.star_of_cell, catalog.grid
    radius = 2.0 * math.asin(min(1.0, 0.5 * chord))
    cos_limit = 1.0 - 0.5 * chord * chord
    px = rotation[0, 0] * ray[0] + rotation[0, 1] * ray[1] + rotation[0, 2] * ray[2]
    py = rotation[1, 0] * ray[0] + rotation[1, 1] * ray[1] + rotation[1, 2] * ray[2]
    pz = rotation[2, 0] * ray[0] + rotation[2, 1] * ray[1] + rotation[2, 2] * ray[2]
    best, best_dot = -1, -2.0
    for q in range(cells_near(px, py, pz, radius, grid, cells)):
        c = cells[q]
        for e in range(cell_start[c], cell_start[c + 1]):
            star = star_of_cell[e]
            dot = px * vectors[star, 0] + py * vectors[star, 1] + pz * vectors[star, 2]
            if dot >= cos_limit and dot > best_dot:
                best, best_dot = star, dot
    return best, best_dot


@njit(cache=True)
def lands_on_star(rays, skip_a, skip_b, skip_c, limit, rotation, catalog, chord):
    """
    Tell whether any other spot lands on a catalog star under `rotation`.

    True when any spot in [0, limit) other than the three given lands within `chord` of a
    catalog star under `rotation`: the pyramid's 4th-star confirmation, used as a screen.
    """
    cells = np.empty(4, np.int64)
    for s in range(min(limit, rays.shape[0])):
        if s != skip_a and s != skip_b and s != skip_c:
            if nearest_star(rotation, rays[s], chord, catalog, cells)[0] >= 0:
                return True
    return False


# Slack [chord] of match_all's rival sweep beyond the wide chord: rounding is ~1e-15, so no
# spot the full test would find a rival falls outside the swept range.
RIVAL_SWEEP_MARGIN = 1e-8


@njit(cache=True)
def match_all(rays, rotation, catalog, chord, out_spot, out_star, out_dot):
    """
    One-to-one matches of every spot ray (rotated to ICRS) with the nearest catalog star.

    The nearest star of the catalog (CatalogArrays) within `chord` (2 sin(radius/2)); a star
    with another spot within twice the radius matches no spot (ambiguous). Returns the number
    of matches written to out_*.
    """
    n = rays.shape[0]
    vectors = catalog.vectors
    radius = 2.0 * math.asin(min(1.0, 0.5 * chord))
    cells = np.empty(4, np.int64)
    best_star = np.full(n, -1, np.int64)
    best_dot = np.full(n, -2.0)
    for s in range(n):
        best_star[s], best_dot[s] = nearest_star(rotation, rays[s], chord, catalog, cells)
    # A star with a second spot within twice the radius is ambiguous (e.g. a false object
    # beside a star that pulled the fit toward itself): no spot is matched to it, so no
    # identity can be claimed for the wrong one.
    cos_wide = math.cos(min(2.0 * radius, math.pi))
    world = np.empty((n, 3))  # the rays in ICRS under `rotation`, once
    for t in range(n):
        for a in range(3):
            world[t, a] = rotation[a, 0] * rays[t, 0] + rotation[a, 1] * rays[t, 1] + rotation[a, 2] * rays[t, 2]
    # Rivals are looked for among the spots whose sensor x lies within the wide chord of the
    # star's (a necessary condition, widened far beyond rounding), sorted by it: the same
    # test as over every spot, in O(n log n) instead of n^2.
    reach = math.sqrt(max(2.0 - 2.0 * cos_wide, 0.0)) + RIVAL_SWEEP_MARGIN
    by_x = np.argsort(rays[:, 0])
    sorted_x = rays[by_x, 0]
    count = 0
    for s in range(n):
        star = best_star[s]
        if star < 0:
            continue
        rivals = 0
        vx, vy, vz = vectors[star, 0], vectors[star, 1], vectors[star, 2]
        star_x = rotation[0, 0] * vx + rotation[1, 0] * vy + rotation[2, 0] * vz  # sensor x of the star
        first = np.searchsorted(sorted_x, star_x - reach)
        last = np.searchsorted(sorted_x, star_x + reach, side="right")
        for q in range(first, last):
            t = by_x[q]
            if t != s and world[t, 0] * vx + world[t, 1] * vy + world[t, 2] * vz >= cos_wide:
                rivals += 1
                break
        if rivals == 0:
            out_spot[count] = s
            out_star[count] = star
            out_dot[count] = best_dot[s]
            count += 1
    return count


@njit(cache=True)
def log_chance_tuples(body, sigma, chi2, density):
    """Return ln lambda_m(c) of verify.log_chance_tuples."""
    m = body.shape[0]
    info = np.zeros((3, 3))
    total = 0.0
    for i in range(m):
        w = 1.0 / (sigma[i] * sigma[i])
        for r in range(3):
            for c in range(3):
                info[r, c] += w * ((1.0 if r == c else 0.0) - body[i, r] * body[i, c])
        total += math.log(density * sigma[i] * sigma[i])
    det = np.linalg.det(info)
    if det <= 0.0:
        return 0.0
    d = 2 * m - 3
    radius = math.sqrt(max(chi2, 1e-12))
    log_ball = 0.5 * d * LN_PI - math.lgamma(0.5 * d + 1.0) + d * math.log(radius)
    return total + LN_8PI2 + 0.5 * math.log(det) + log_ball


@njit(cache=True)
def log_magnitude_agreement(spot_mag, star_mag, sorted_catalog, floor):
    """Return ln M of verify.log_magnitude_agreement; 0 when fewer than two magnitudes are known."""
    m = spot_mag.size
    offset = np.empty(m)
    count = 0
    for i in range(m):
        if np.isfinite(spot_mag[i]):
            offset[count] = spot_mag[i] - star_mag[i]
            count += 1
    if count < 2:
        return 0.0
    zero_point = np.median(offset[:count])
    half = floor
    for i in range(count):
        half = max(half, abs(offset[i] - zero_point))
    n = sorted_catalog.size
    window = np.empty(count)
    q = 0
    for i in range(m):
        if np.isfinite(spot_mag[i]):
            expected = spot_mag[i] - zero_point
            hi = np.searchsorted(sorted_catalog, expected + half, side="right")
            lo = np.searchsorted(sorted_catalog, expected - half, side="left")
            window[q] = min(max((hi - lo) / n, 1.0 / n), 1.0)
            q += 1
    window.sort()
    total = 0.0
    for i in range(1, count):
        total += math.log(window[i])
    return total


@njit(cache=True)
def false_positive_bound(log_statistic, spots, matched, min_stars):
    """
    Return P_fp of verify.false_positive_bound.

    P_fp = (n - min_stars + 1) C(n, m) T (1 + ln 1/T), the look-elsewhere factor over every subset
    size min_stars..n.
    """
    if matched < min_stars or spots < matched:
        return 1.0
    log_t = min(log_statistic, 0.0)
    log_subsets = math.lgamma(spots + 1.0) - math.lgamma(matched + 1.0) - math.lgamma(spots - matched + 1.0)
    log_p = math.log(spots - min_stars + 1.0) + log_subsets + log_t + math.log1p(-log_t)
    return min(1.0, math.exp(log_p))


@njit(cache=True)
def refit(rays, sigma, vectors, spot_index, star_index, count):
    """q-method attitude (sensor -> ICRS) over the first `count` matches, weights 1/sigma^2."""
    body = np.empty((count, 3))
    ref = np.empty((count, 3))
    w = np.empty(count)
    for i in range(count):
        body[i] = rays[spot_index[i]]
        ref[i] = vectors[star_index[i]]
        w[i] = 1.0 / sigma[spot_index[i]] ** 2
    return q_method(body, ref, w)


@njit(cache=True)
def _same_pairs(spot_a, star_a, spot_b, star_b, count):
    """Whether the first `count` (spot, star) pairs of a and b are the same, in the same order."""
    for i in range(count):
        if spot_a[i] != spot_b[i] or star_a[i] != star_b[i]:
            return False
    return True


@njit(cache=True)
def verify_candidate(rotation, spots, catalog, verification, out_spot, out_star, match_passes=3):
    """
    Match every spot (SpotArrays) to the catalog (CatalogArrays) under `rotation` and verify.

    Refine with the q-method over the matches (match_passes times: a hypothesis from 3-4
    stars needs 3; a tracked attitude, already fitted to a dozen stars, 1), drop matches
    beyond 5 sigma and bound the false-positive probability (VerifySettings: radius, fewest
    stars). Returns a CandidateCheck (the matches are written to out_*).
    """
    rays, sigma, magnitude = spots.rays, spots.sigma, spots.magnitude
    vectors = catalog.vectors
    chord, min_stars = verification.chord, verification.min_stars
    n = rays.shape[0]
    dots = np.empty(n)
    count = 0
    last_spot = np.empty(n, np.int64)
    last_star = np.empty(n, np.int64)
    last_count = -1
    for _ in range(match_passes):  # match, refit; each match uses the previous refit
        count = match_all(rays, rotation, catalog, chord, out_spot, out_star, dots)
        if count < min_stars:
            return CandidateCheck(count, rotation, 1.0, 0.0)
        if count == last_count and _same_pairs(out_spot, out_star, last_spot, last_star, count):
            break  # the matches the rotation was fitted to: every further pass would repeat it exactly
        last_count = count
        last_spot[:count] = out_spot[:count]
        last_star[:count] = out_star[:count]
        rotation = refit(rays, sigma, vectors, out_spot, out_star, count)
    kept = count
    chi2 = 0.0
    for _ in range(2):  # drop 5-sigma outliers, refit once
        kept = 0
        chi2 = 0.0
        for i in range(count):
            s, t = out_spot[i], out_star[i]
            r2 = 0.0
            for a in range(3):
                pred = rotation[0, a] * vectors[t, 0] + rotation[1, a] * vectors[t, 1] + rotation[2, a] * vectors[t, 2]
                r2 += (rays[s, a] - pred) ** 2
            r2 /= sigma[s] ** 2
            if r2 <= 25.0:
                out_spot[kept] = s
                out_star[kept] = t
                chi2 += r2
                kept += 1
        if kept < min_stars:
            return CandidateCheck(kept, rotation, 1.0, 0.0)
        if kept == count:
            break
        count = kept
        rotation = refit(rays, sigma, vectors, out_spot, out_star, count)
    count = kept
    body = np.empty((count, 3))
    sig = np.empty(count)
    smag = np.empty(count)
    cmag = np.empty(count)
    for i in range(count):
        body[i] = rays[out_spot[i]]
        sig[i] = sigma[out_spot[i]]
        smag[i] = magnitude[out_spot[i]]
        cmag[i] = catalog.magnitude[out_star[i]]
    density = max(catalog.mean_density,
                  catalog.cell_density[cell_of(rotation[0, 2], rotation[1, 2], rotation[2, 2], catalog.grid)])
    log_t = log_chance_tuples(body, sig, chi2, density)
    log_t += log_magnitude_agreement(smag, cmag, catalog.sorted_magnitudes, verification.magnitude_floor)
    return CandidateCheck(count, rotation, false_positive_bound(log_t, n, count, min_stars), chi2)


@njit(cache=True)
def search_triangles(triangles, first, last, spots, pairs, catalog, tolerances, verification, scratch,
                     screen_limit):
    """
    Try spot triangles triangles[first:last] in order.

    Catalog triangles whose three sides match within the angle tolerance (TriangleTolerances)
    in the pair index (PairIndex) and whose handedness agrees (mirror test) are verified
    against all spots (SpotArrays) at once (verify_candidate). Returns a TriangleSearchResult
    (accepted matches in scratch.out_*). screen_limit: spots [0, screen_limit) are tried for
    the 4th-star screen.
    """
    rays, sigma = spots.rays, spots.sigma
    sigma_multiplier, tolerance_floor = tolerances.sigma_multiplier, tolerances.tolerance_floor
    max_candidates = tolerances.max_candidates
    pair_angle, k, slope, intercept = pairs.pair_angle, pairs.k, pairs.slope, pairs.intercept
    pair_a, pair_b = pairs.pair_a, pairs.pair_b
    vectors, chord = catalog.vectors, verification.chord
    head_ik, head_jk = scratch.head_ik, scratch.head_jk
    hypotheses = 0
    best_rotation = np.eye(3)
    for t in range(first, last):
        i, j, kk = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        spot = (i, j, kk)
        lo = np.empty(3, np.int64)
        hi = np.empty(3, np.int64)
        empty = False
        for e in range(3):
            a, b = (i, j) if e == 0 else ((i, kk) if e == 1 else (j, kk))
            angle = angle_between(rays[a], rays[b])
            tol = sigma_multiplier * math.sqrt(sigma[a] ** 2 + sigma[b] ** 2) + tolerance_floor
            lo[e], hi[e] = kvector_range(pair_angle, k, slope, intercept, angle - tol, angle + tol)
            if hi[e] <= lo[e]:
                empty = True
        if empty:
            continue
        # Adjacency lists (linked through `nxt`) of the i-k and j-k windows, both orientations.
        size_ik = 2 * (hi[1] - lo[1])
        size_jk = 2 * (hi[2] - lo[2])
        nxt_ik = np.empty(size_ik, np.int64)
        to_ik = np.empty(size_ik, np.int64)
        nxt_jk = np.empty(size_jk, np.int64)
        to_jk = np.empty(size_jk, np.int64)
        e = 0
        for p in range(lo[1], hi[1]):
            for a, b in ((pair_a[p], pair_b[p]), (pair_b[p], pair_a[p])):
                nxt_ik[e] = head_ik[a]
                to_ik[e] = b
                head_ik[a] = e
                e += 1
        e = 0
        for p in range(lo[2], hi[2]):
            for a, b in ((pair_a[p], pair_b[p]), (pair_b[p], pair_a[p])):
                nxt_jk[e] = head_jk[a]
                to_jk[e] = b
                head_jk[a] = e
                e += 1
        spot_sign = triple_product_rows(rays, i, j, kk)
        cand = np.empty((max_candidates + 1, 3), np.int64)
        n_cand = 0
        for p in range(lo[0], hi[0]):
            for sa, sb in ((pair_a[p], pair_b[p]), (pair_b[p], pair_a[p])):
                q = head_ik[sa]
                while q >= 0 and n_cand <= max_candidates:
                    sc = to_ik[q]
                    q = nxt_ik[q]
                    if sc == sb:
                        continue
                    r = head_jk[sb]
                    found = False
                    while r >= 0:
                        if to_jk[r] == sc:
                            found = True
                            break
                        r = nxt_jk[r]
                    if not found:
                        continue
                    star_sign = triple_product_rows(vectors, sa, sb, sc)
                    if (star_sign > 0) != (spot_sign > 0):
                        continue  # mirror image
                    cand[n_cand, 0], cand[n_cand, 1], cand[n_cand, 2] = sa, sb, sc
                    n_cand += 1
        # Restore the scratch heads.
        for p in range(lo[1], hi[1]):
            head_ik[pair_a[p]] = -1
            head_ik[pair_b[p]] = -1
        for p in range(lo[2], hi[2]):
            head_jk[pair_a[p]] = -1
            head_jk[pair_b[p]] = -1
        if n_cand > max_candidates:
            continue  # ambiguous triangle: others will do
        for c in range(n_cand):
            hypotheses += 1
            # Screen with a TRIAD attitude: the full verification (q-method refits) only runs
            # when a spot beyond the triangle (among the first `screen_limit`) lands on a star.
            rotation = triad(rays[i], rays[j], vectors[cand[c, 0]], vectors[cand[c, 1]])
            if not lands_on_star(rays, i, j, kk, screen_limit, rotation, catalog, chord):
                continue
            body = np.empty((3, 3))
            ref = np.empty((3, 3))
            w = np.empty(3)
            for q in range(3):
                body[q] = rays[spot[q]]
                ref[q] = vectors[cand[c, q]]
                w[q] = 1.0 / sigma[spot[q]] ** 2
            rotation = q_method(body, ref, w)  # all three stars, weighted: better than TRIAD
            check = verify_candidate(rotation, spots, catalog, verification, scratch.out_spot, scratch.out_star)
            if check.fp <= tolerances.fp_limit:
                return TriangleSearchResult(1, check.count, check.rotation, check.fp, hypotheses, t + 1)
    return TriangleSearchResult(0, 0, best_rotation, 1.0, hypotheses, last)
