"""Compiled identification kernels (numba): triangle search over the pair k-vector, the
q-method, spot-to-star matching on the sky grid and the false-positive bound of `verify`,
in one call per batch of spot triangles so a frame costs microseconds, not Python overhead.

The mathematics is the one documented in base.py and verify.py; these are its loops.
Kernels take their inputs as small records (NamedTuples of arrays and scalars, which numba
passes as they are): the catalog, the spots, the pair index, the tolerances.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .skygrid import SkyGrid, cell_of, cells_near

LN_8PI2 = math.log(8.0 * math.pi**2)
LN_PI = math.log(math.pi)


class CatalogArrays(NamedTuple):
    """The database stars as the kernels read them: vectors (N, 3) ICRS unit vectors;
    magnitude (N,) [Hp mag]; sorted_magnitudes (N,) the same, ascending; the sky grid
    (skygrid.SkyGrid: cell_start, star_of_cell, grid, cell_density [1/sr]); mean_density:
    the whole catalog's stars per steradian [1/sr]."""

    vectors: np.ndarray
    magnitude: np.ndarray
    sorted_magnitudes: np.ndarray
    cell_start: np.ndarray
    star_of_cell: np.ndarray
    grid: int
    cell_density: np.ndarray
    mean_density: float

    @staticmethod
    def build(database, grid: SkyGrid) -> "CatalogArrays":
        """The arrays of `database` (identify.database.StarDatabase) on `grid` (built over its
        vectors)."""
        magnitude = np.asarray(database.magnitude, dtype=float)
        return CatalogArrays(np.ascontiguousarray(database.vectors, dtype=float), magnitude, np.sort(magnitude),
                             grid.cell_start, grid.star_of_cell, grid.grid, grid.cell_density,
                             database.star_count / (4.0 * np.pi))


class PairIndex(NamedTuple):
    """The star pairs sorted by angle and their k-vector (kvector.KVector): pair_angle (P,)
    [rad]; k (P,); slope, intercept of the k-vector line; pair_a, pair_b (P,) star indices."""

    pair_angle: np.ndarray
    k: np.ndarray
    slope: float
    intercept: float
    pair_a: np.ndarray
    pair_b: np.ndarray

    @staticmethod
    def build(database) -> "PairIndex":
        kv = database.kvector
        return PairIndex(kv.sorted_values, kv.k.astype(np.int64), float(kv.slope), float(kv.intercept),
                         database.pair_a.astype(np.int64), database.pair_b.astype(np.int64))


class SpotArrays(NamedTuple):
    """Flux-sorted spots (base.SpotGeometry): rays (N, 3) sensor-frame unit vectors; sigma
    (N,) 1-sigma direction errors [rad]; magnitude (N,) instrumental [mag] (NaN: unknown)."""

    rays: np.ndarray
    sigma: np.ndarray
    magnitude: np.ndarray


class Verification(NamedTuple):
    """How a candidate attitude is verified (verify_candidate): chord of the match radius,
    2 sin(radius / 2); min_stars: fewest matches accepted; magnitude_floor: smallest
    magnitude residual credited [mag] (verify.log_magnitude_agreement)."""

    chord: float
    min_stars: int
    magnitude_floor: float


class TriangleTolerances(NamedTuple):
    """search_triangles' pattern tolerances: a side matches within sigma_multiplier x its
    angle sigma plus tolerance_floor [rad]; a triangle with more than max_candidates catalog
    matches is ambiguous; a candidate is accepted at a false-positive bound <= fp_limit."""

    sigma_multiplier: float
    tolerance_floor: float
    max_candidates: int
    fp_limit: float


class SearchScratch(NamedTuple):
    """Work arrays of search_triangles: head_ik, head_jk (N stars,) all -1 (restored on
    return); out_spot, out_star (spots,) the accepted matches."""

    head_ik: np.ndarray
    head_jk: np.ndarray
    out_spot: np.ndarray
    out_star: np.ndarray


class TriangleSearchResult(NamedTuple):
    """status 1 = a candidate accepted (its `count` matches in the scratch's out_*), 0 = none
    in the batch; rotation sensor -> ICRS; fp its false-positive bound; hypotheses tested;
    stopped: index after the last triangle tried."""

    status: int
    count: int
    rotation: np.ndarray
    fp: float
    hypotheses: int
    stopped: int


class CandidateCheck(NamedTuple):
    """verify_candidate's verdict: count matches (in out_*), the refined rotation (sensor ->
    ICRS), its false-positive bound fp and chi^2 (0 when rejected early)."""

    count: int
    rotation: np.ndarray
    fp: float
    chi2: float


class Pinhole(NamedTuple):
    """A camera without distortion: fx, fy, cx, cy [px]; width, height [px]."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: float
    height: float

    @staticmethod
    def of(camera) -> "Pinhole":
        """The pinhole part of a models.camera.CameraModel."""
        return Pinhole(float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy),
                       float(camera.width), float(camera.height))


class RawSpots(NamedTuple):
    """Spots as the centroider gives them: x, y (N,) [px]; flux (N,); cov (N, 2, 2) [px^2]."""

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    cov: np.ndarray


class PrepareSettings(NamedTuple):
    """prepare_spots' floors: sigma_floor_px, the matching sigma's lower bound [px];
    min_fit_sigma_px added to the final fit's sigma [px]; separation_px: closer spots are
    one [px]."""

    sigma_floor_px: float
    min_fit_sigma_px: float
    separation_px: float


class PreparedSpots(NamedTuple):
    """prepare_spots' output (base.SpotGeometry's arrays): order (M,) indices into the input;
    rays (M, 3); sigma (M,) [rad]; magnitude (M,); x, y (M,) [px]; pixel_cov (M, 2, 2)
    [px^2]; jacobian (M, 3, 2) [rad/px]."""

    order: np.ndarray
    rays: np.ndarray
    sigma: np.ndarray
    magnitude: np.ndarray
    x: np.ndarray
    y: np.ndarray
    pixel_cov: np.ndarray
    jacobian: np.ndarray


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
    """Sensor -> ICRS rotation taking b1 exactly onto r1 and b2 into the r1-r2 plane (TRIAD):
    a cheap first attitude for screening candidates."""
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
    """The catalog star (CatalogArrays) nearest to the sensor-frame `ray` rotated to ICRS, if
    within `chord` (2 sin(radius/2)): (star index or -1, dot product). `cells`: scratch of 4."""
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
    """True when any spot in [0, limit) other than the three given lands within `chord` of a
    catalog star under `rotation`: the pyramid's 4th-star confirmation, used as a screen."""
    cells = np.empty(4, np.int64)
    for s in range(min(limit, rays.shape[0])):
        if s != skip_a and s != skip_b and s != skip_c:
            if nearest_star(rotation, rays[s], chord, catalog, cells)[0] >= 0:
                return True
    return False


@njit(cache=True)
def match_all(rays, rotation, catalog, chord, out_spot, out_star, out_dot):
    """One-to-one matches of every spot ray (rotated to ICRS) with the nearest catalog star
    (CatalogArrays) within `chord` (2 sin(radius/2)); a star with another spot within twice
    the radius matches no spot (ambiguous). Returns the number of matches written to out_*."""
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
    world = np.empty((n, 3))  # the rays in ICRS under `rotation`, once (the rival scan is n^2)
    for t in range(n):
        for a in range(3):
            world[t, a] = rotation[a, 0] * rays[t, 0] + rotation[a, 1] * rays[t, 1] + rotation[a, 2] * rays[t, 2]
    count = 0
    for s in range(n):
        star = best_star[s]
        if star < 0:
            continue
        rivals = 0
        vx, vy, vz = vectors[star, 0], vectors[star, 1], vectors[star, 2]
        for t in range(n):
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
    """ln lambda_m(c) of verify.log_chance_tuples."""
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
    """ln M of verify.log_magnitude_agreement (0 when fewer than two magnitudes are known)."""
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
    """P_fp of verify.false_positive_bound: (n - min_stars + 1) C(n, m) T (1 + ln 1/T), the
    look-elsewhere factor over every subset size min_stars..n."""
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
def verify_candidate(rotation, spots, catalog, verification, out_spot, out_star, match_passes=3):
    """Match every spot (SpotArrays) to the catalog (CatalogArrays) under `rotation`, refine
    with the q-method over the matches (match_passes times: a hypothesis from 3-4 stars needs
    3; a tracked attitude, already fitted to a dozen stars, 1), drop matches beyond 5 sigma
    and bound the false-positive probability (Verification: radius, fewest stars).
    Returns a CandidateCheck (the matches are written to out_*)."""
    rays, sigma, magnitude = spots.rays, spots.sigma, spots.magnitude
    vectors = catalog.vectors
    chord, min_stars = verification.chord, verification.min_stars
    n = rays.shape[0]
    dots = np.empty(n)
    count = 0
    for _ in range(match_passes):  # match, refit; each match uses the previous refit
        count = match_all(rays, rotation, catalog, chord, out_spot, out_star, dots)
        if count < min_stars:
            return CandidateCheck(count, rotation, 1.0, 0.0)
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
    """Try spot triangles triangles[first:last] in order: catalog triangles whose three sides
    match within the angle tolerance (TriangleTolerances) in the pair index (PairIndex) and
    whose handedness agrees (mirror test) are verified against all spots (SpotArrays) at once
    (verify_candidate). Returns a TriangleSearchResult (accepted matches in scratch.out_*).
    screen_limit: spots [0, screen_limit) are tried for the 4th-star screen."""
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
            dx = rays[a, 0] - rays[b, 0]
            dy = rays[a, 1] - rays[b, 1]
            dz = rays[a, 2] - rays[b, 2]
            angle = 2.0 * math.asin(min(1.0, 0.5 * math.sqrt(dx * dx + dy * dy + dz * dz)))
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
        spot_sign = (rays[i, 0] * (rays[j, 1] * rays[kk, 2] - rays[j, 2] * rays[kk, 1])
                     - rays[i, 1] * (rays[j, 0] * rays[kk, 2] - rays[j, 2] * rays[kk, 0])
                     + rays[i, 2] * (rays[j, 0] * rays[kk, 1] - rays[j, 1] * rays[kk, 0]))
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
                    va, vb, vc = vectors[sa], vectors[sb], vectors[sc]
                    star_sign = (va[0] * (vb[1] * vc[2] - vb[2] * vc[1]) - va[1] * (vb[0] * vc[2] - vb[2] * vc[0])
                                 + va[2] * (vb[0] * vc[1] - vb[1] * vc[0]))
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


@njit(cache=True)
def prepare_spots(raw, camera, settings):
    """The compiled form of StarIdentifier.prepare for cameras without distortion (Pinhole),
    as PreparedSpots: indices of the usable spots (RawSpots: finite, not coincident:
    coincident_later) sorted by flux (brightest first, NaN flux last, stable), their unit rays
    (N, 3), 1-sigma direction errors [rad] for matching (floored at sigma_floor_px),
    instrumental magnitudes (NaN for flux <= 0), pixel positions x, y [px], pixel covariances
    for the final fit (N, 2, 2) [px^2] (unknown: 1 px^2, plus min_fit_sigma_px^2 on both axes)
    and the rays' pixel jacobians (N, 3, 2) [rad/px] (PrepareSettings: the floors)."""
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
    """(N, 3, 2) d ray / d pixel [rad/px] of pinhole unit rays (N, 3):
    r_z (I - r r^T)[:, :2] diag(1/fx, 1/fy)."""
    out = np.empty((rays.shape[0], 3, 2))
    for i in range(rays.shape[0]):
        a, b = rays[i, 2] / fx, rays[i, 2] / fy
        for r in range(3):
            out[i, r, 0] = a * ((1.0 if r == 0 else 0.0) - rays[i, r] * rays[i, 0])
            out[i, r, 1] = b * ((1.0 if r == 1 else 0.0) - rays[i, r] * rays[i, 1])
    return out


@njit(cache=True)
def coincident_later(x, y, separation_px):
    """(N,) bool: spots within separation_px [px] of an earlier (lower-index) finite spot.
    Sweep over x-sorted finite spots, O(N log N) for spread-out spots."""
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


@njit(cache=True)
def log_chance_tuples_in_region(body, sigma, chi2, density, region_covariance, region_sigma):
    """ln of the expected chance m-tuples fitting `body` with chi^2 <= `chi2` under an attitude
    inside the region_sigma ellipsoid of `region_covariance` [rad^2]: log_chance_tuples with
    the volume of SO(3) replaced by the searched region when that is smaller (see
    tracking.log_chance_tuples_in_region for the math)."""
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
    """One-to-one pairs within `radius` [px]: a spot with exactly one reference within the
    radius, whose reference has no other spot within it. Returns (spot idx, ref idx)."""
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
    """Catalog stars (ICRS unit vectors) within acos(cos_reach) of the boresight of `rotation`
    (sensor -> ICRS) that a pinhole camera (Pinhole) puts inside its pixel area shrunk by
    `margin` [px] (negative: grown): (indices, u, v [px]). One pass over the catalog (~8k
    stars)."""
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
    """Squared Mahalanobis distance of `rotation` from `predicted` (both sensor -> ICRS): the
    rotation vector of predicted^T rotation [rad] (sensor frame) against `covariance` [rad^2]."""
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
