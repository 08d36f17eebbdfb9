"""Star-triangle features and the catalog triangle database with k-vectors on area.

Two feature pairs describe a star triangle independently of attitude:

* spherical (Cole & Crassidis 2006, Cole's thesis): the area A from the spherical excess,
  l'Huilier's formula (eqs. 15-16), with its analytic 1-sigma from linearization
  (eqs. 17-24), and the polar moment I_p = sum theta^2 dA (eq. 25) about the triangle's
  centroid, by recursive subdivision into 4^depth sub-triangles (the thesis uses depth 3);
* planar (Toloei et al. 2014): the area of the triangle with side lengths a, b, c by Heron's
  formula with s = (a+b+c)/2 (eq. 1) and the polar moment I = A (a^2+b^2+c^2)/36 (eq. 2).

Side lengths are the inter-star angles a = d12, b = d23, c = d31 [rad]; areas are [sr]
(spherical) or [rad^2] (planar), polar moments [sr rad^2] or [rad^4].

Uncertainties: every feature F(a, b, c) is linearized in the three sides,
sigma_F^2 = H R H^T with H = dF/d(a, b, c) (eq. 19). Cole's eq. 24 takes the sides as
independent; here R is the sides' actual covariance: star i's direction error (1-sigma
s_i per axis) moves both sides meeting at it, so var(d12) = s_1^2 + s_2^2 and
cov(d12, d31) = s_1^2 cos(angle at star 1). The thesis bounds the polar moment's sigma by
simulation (a line above the worst case); here its H is taken by central differences of the
same subdivision, which follows each triangle's shape.

The catalog database holds every triangle of guide stars whose three sides are at most
`max_side_rad`, with star indices sorted ascending (so a triangle's handedness is the sign
of det[v_a, v_b, v_c]). Each feature pair has its own ordering (Cole keeps pointer arrays
sorted by each property): rows by area, in blocks of 64 re-sorted by moment, so a k-vector
over the blocks gives the area window and a binary search per block the moment window (the
"finalists") without a scan. A third invariant, the side product a b c, completes the
shape (with area and moment it fixes the triangle up to reflection); it screens finalists
before their vertices are assigned to the spots by the sides. For wide fields the full
catalog gives tens of millions of triangles, so guide stars are thinned to the brightest
`stars_per_cell` of each cell of an equal-angle cube-sphere grid, the grid as fine as the
triangle budget allows (uniform sky coverage, brightest stars kept).
"""
from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numba
import numpy as np
from numba import njit

from ..models.catalog import cache_dir, load_validated_npz, save_validated_npz
from .database import StarDatabase
from .kvector import KVector

TRIANGLE_FORMAT_VERSION = 3
DEFAULT_MAX_SIDE_RAD = float(np.radians(8.0))


# ----------------------------------------------------------------------------------------
# Scalar geometry (numba). Vectors are unit 3-vectors (rows of float64 arrays).

@njit(cache=True, inline="always")
def _arc(u, v) -> float:
    """Angle between unit vectors [rad]: 2 asin(|u - v| / 2), accurate at small angles."""
    dx, dy, dz = u[0] - v[0], u[1] - v[1], u[2] - v[2]
    return 2.0 * math.asin(min(1.0, 0.5 * math.sqrt(dx * dx + dy * dy + dz * dz)))


@njit(cache=True, inline="always")
def _det(u, v, w) -> float:
    """Triple product u . (v x w): positive for a counter-clockwise (right-handed) triple."""
    return (u[0] * (v[1] * w[2] - v[2] * w[1]) + u[1] * (v[2] * w[0] - v[0] * w[2])
            + u[2] * (v[0] * w[1] - v[1] * w[0]))


@njit(cache=True)
def _lhuilier_area(a: float, b: float, c: float) -> float:
    """Spherical area from the sides (eqs. 15-16) [sr]; 0 for degenerate triangles."""
    s = 0.5 * (a + b + c)
    t = math.tan(0.5 * s) * math.tan(0.5 * (s - a)) * math.tan(0.5 * (s - b)) * math.tan(0.5 * (s - c))
    return 4.0 * math.atan(math.sqrt(t)) if t > 0.0 else 0.0


@njit(cache=True)
def _lhuilier_jacobian(a: float, b: float, c: float, out) -> None:
    """dA/d(a, b, c) of the spherical area (eqs. 20-23; the sign follows from
    differentiating z^2, Cole's leading minus does not affect H H^T)."""
    q0, q1, q2, q3 = 0.25 * (a + b + c), 0.25 * (b + c - a), 0.25 * (a + c - b), 0.25 * (a + b - c)
    t0, t1, t2, t3 = math.tan(q0), math.tan(q1), math.tan(q2), math.tan(q3)
    z2 = t0 * t1 * t2 * t3
    if z2 <= 0.0:
        out[0] = out[1] = out[2] = np.inf
        return
    z = math.sqrt(z2)
    u1 = t1 * t2 * t3 / math.cos(q0) ** 2
    u2 = t0 * t2 * t3 / math.cos(q1) ** 2
    u3 = t0 * t1 * t3 / math.cos(q2) ** 2
    u4 = t0 * t1 * t2 / math.cos(q3) ** 2
    scale = 4.0 / (1.0 + z2) / (8.0 * z)
    out[0] = scale * (u1 - u2 + u3 + u4)
    out[1] = scale * (u1 + u2 - u3 + u4)
    out[2] = scale * (u1 + u2 + u3 - u4)


@njit(cache=True)
def _heron_area(a: float, b: float, c: float) -> float:
    """Planar area of the triangle with sides a, b, c (Heron, Toloei eq. 1) [rad^2]."""
    p = (a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c)
    return 0.25 * math.sqrt(p) if p > 0.0 else 0.0


@njit(cache=True)
def _planar_jacobians(a: float, b: float, c: float, d_area, d_moment) -> None:
    """d(area)/d(a, b, c) and d(moment)/d(a, b, c) of Toloei's eqs. 1-2."""
    area = _heron_area(a, b, c)
    if area <= 0.0:
        for k in range(3):
            d_area[k] = d_moment[k] = np.inf
        return
    q = a * a + b * b + c * c
    d_area[0] = a * (b * b + c * c - a * a) / (8.0 * area)
    d_area[1] = b * (a * a + c * c - b * b) / (8.0 * area)
    d_area[2] = c * (a * a + b * b - c * c) / (8.0 * area)
    sides = (a, b, c)
    for k in range(3):
        d_moment[k] = (d_area[k] * q + 2.0 * area * sides[k]) / 36.0


@njit(cache=True)
def _normalize_sum(x0, y0, z0, x1, y1, z1, x2, y2, z2):
    x, y, z = x0 + x1 + x2, y0 + y1 + y2, z0 + z1 + z2
    n = math.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n


@njit(cache=True, inline="always")
def _small_atan(x: float) -> float:
    """atan(x) for x >= 0; a short series where it is exact to double precision."""
    if x < 1e-3:
        x2 = x * x
        return x * (1.0 - x2 * (1.0 / 3.0 - x2 * 0.2))
    return math.atan(x)


@njit(cache=True, inline="always")
def _small_asin(y: float) -> float:
    """asin(y) for 0 <= y <= 1; a short series where it is exact to ~1e-13 relative."""
    if y < 0.02:
        y2 = y * y
        return y * (1.0 + y2 * (1.0 / 6.0 + y2 * (3.0 / 40.0 + y2 * (15.0 / 336.0))))
    return math.asin(min(1.0, y))


@njit(cache=True)
def moment_workspace(depth: int) -> np.ndarray:
    """Scratch buffer for `_polar_moment` at `depth`."""
    return np.empty((2, 4**depth, 9))


@njit(cache=True)
def _polar_moment(v1, v2, v3, depth: int, work) -> float:
    """Cole's spherical polar moment (eq. 25): split the triangle into four at its
    (normalized) edge midpoints, `depth` times (the children tile the parent exactly), and
    sum over the 4^depth leaves the leaf area dA times the squared arc theta from the leaf
    centroid to the triangle centroid; centroids are normalized vertex sums.
    `work` is moment_workspace(depth). (Indexing, not slicing: array views cost here.)"""
    gx, gy, gz = _normalize_sum(v1[0], v1[1], v1[2], v2[0], v2[1], v2[2], v3[0], v3[1], v3[2])
    cur = 0
    for k in range(3):
        work[0, 0, k], work[0, 0, 3 + k], work[0, 0, 6 + k] = v1[k], v2[k], v3[k]
    count = 1
    for _ in range(depth):
        nxt = 1 - cur
        for t in range(count - 1, -1, -1):
            ax, ay, az = work[cur, t, 0], work[cur, t, 1], work[cur, t, 2]
            bx, by, bz = work[cur, t, 3], work[cur, t, 4], work[cur, t, 5]
            cx, cy, cz = work[cur, t, 6], work[cur, t, 7], work[cur, t, 8]
            mabx, maby, mabz = _normalize_sum(ax, ay, az, bx, by, bz, 0.0, 0.0, 0.0)
            mbcx, mbcy, mbcz = _normalize_sum(bx, by, bz, cx, cy, cz, 0.0, 0.0, 0.0)
            mcax, mcay, mcaz = _normalize_sum(cx, cy, cz, ax, ay, az, 0.0, 0.0, 0.0)
            o = 4 * t
            _put(work, nxt, o, ax, ay, az, mabx, maby, mabz, mcax, mcay, mcaz)
            _put(work, nxt, o + 1, bx, by, bz, mbcx, mbcy, mbcz, mabx, maby, mabz)
            _put(work, nxt, o + 2, cx, cy, cz, mcax, mcay, mcaz, mbcx, mbcy, mbcz)
            _put(work, nxt, o + 3, mabx, maby, mabz, mbcx, mbcy, mbcz, mcax, mcay, mcaz)
        count *= 4
        cur = nxt
    total = 0.0
    for t in range(count):
        ax, ay, az = work[cur, t, 0], work[cur, t, 1], work[cur, t, 2]
        bx, by, bz = work[cur, t, 3], work[cur, t, 4], work[cur, t, 5]
        cx, cy, cz = work[cur, t, 6], work[cur, t, 7], work[cur, t, 8]
        # Leaf area from the triple-product form of the excess: tan(E/2) = |det| / (1 + sum of dots).
        det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
        dots = 1.0 + (ax * bx + ay * by + az * bz) + (bx * cx + by * cy + bz * cz) + (cx * ax + cy * ay + cz * az)
        d_area = 2.0 * _small_atan(abs(det) / dots) if dots > 0.0 else 2.0 * math.atan2(abs(det), dots)
        lx, ly, lz = _normalize_sum(ax, ay, az, bx, by, bz, cx, cy, cz)
        theta = 2.0 * _small_asin(0.5 * math.sqrt((lx - gx) ** 2 + (ly - gy) ** 2 + (lz - gz) ** 2))
        total += theta * theta * d_area
    return total


@njit(cache=True, inline="always")
def _put(work, level, row, ax, ay, az, bx, by, bz, cx, cy, cz) -> None:
    work[level, row, 0], work[level, row, 1], work[level, row, 2] = ax, ay, az
    work[level, row, 3], work[level, row, 4], work[level, row, 5] = bx, by, bz
    work[level, row, 6], work[level, row, 7], work[level, row, 8] = cx, cy, cz


def subdivision_tables(depth: int) -> tuple[np.ndarray, np.ndarray]:
    """The subdivision of `_polar_moment` as index tables over a shared vertex list (corners
    0, 1, 2): ops (V, 2), vertex 3 + o is the normalized sum of vertices ops[o] (each edge
    midpoint once); leaves (4^depth, 3), the vertex indices of the final sub-triangles."""
    ops: list[tuple[int, int]] = []
    midpoint: dict[tuple[int, int], int] = {}
    triangles = [(0, 1, 2)]
    for _ in range(depth):
        children = []
        for a, b, c in triangles:
            m = []
            for p, q in ((a, b), (b, c), (c, a)):
                key = (min(p, q), max(p, q))
                if key not in midpoint:
                    midpoint[key] = 3 + len(ops)
                    ops.append((p, q))
                m.append(midpoint[key])
            mab, mbc, mca = m
            children += [(a, mab, mca), (b, mbc, mab), (c, mca, mbc), (mab, mbc, mca)]
        triangles = children
    return np.array(ops, np.int64).reshape(-1, 2), np.array(triangles, np.int64)


_LANES = 16  # triangles processed side by side (SIMD across triangles)


@njit(cache=True, fastmath=True)
def _polar_moment_lanes(vectors, stars, start, stop, ops, leaves, vert, centroid, acc, worst, out) -> None:
    """`_polar_moment` for catalog triangles stars[start:stop] (rows of indices into
    `vectors`), _LANES at a time so the arithmetic vectorizes: atan and asin become their
    series, good to ~1e-9 while leaves have tan(dA/2) < 0.01 and lie within 0.2 rad of the
    centroid; out = -1 marks triangles beyond that (sides > ~20 deg) for an exact redo."""
    for first in range(start, stop, _LANES):
        m = min(_LANES, stop - first)
        for lane in range(_LANES):
            t = first + lane if lane < m else first
            for corner in range(3):
                for k in range(3):
                    vert[corner, k, lane] = vectors[stars[t, corner], k]
        for lane in range(_LANES):
            x = vert[0, 0, lane] + vert[1, 0, lane] + vert[2, 0, lane]
            y = vert[0, 1, lane] + vert[1, 1, lane] + vert[2, 1, lane]
            z = vert[0, 2, lane] + vert[1, 2, lane] + vert[2, 2, lane]
            r = 1.0 / math.sqrt(x * x + y * y + z * z)
            centroid[0, lane], centroid[1, lane], centroid[2, lane] = x * r, y * r, z * r
        for o in range(ops.shape[0]):
            p, q = ops[o, 0], ops[o, 1]
            for lane in range(_LANES):
                x = vert[p, 0, lane] + vert[q, 0, lane]
                y = vert[p, 1, lane] + vert[q, 1, lane]
                z = vert[p, 2, lane] + vert[q, 2, lane]
                r = 1.0 / math.sqrt(x * x + y * y + z * z)
                vert[3 + o, 0, lane], vert[3 + o, 1, lane], vert[3 + o, 2, lane] = x * r, y * r, z * r
        acc[:] = 0.0
        worst[:] = 0.0
        for f in range(leaves.shape[0]):
            i, j, k = leaves[f, 0], leaves[f, 1], leaves[f, 2]
            for lane in range(_LANES):
                ax, ay, az = vert[i, 0, lane], vert[i, 1, lane], vert[i, 2, lane]
                bx, by, bz = vert[j, 0, lane], vert[j, 1, lane], vert[j, 2, lane]
                cx, cy, cz = vert[k, 0, lane], vert[k, 1, lane], vert[k, 2, lane]
                det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
                dots = (1.0 + (ax * bx + ay * by + az * bz) + (bx * cx + by * cy + bz * cz)
                        + (cx * ax + cy * ay + cz * az))
                x = abs(det) / dots  # tan(dA / 2)
                x2 = x * x
                d_area = 2.0 * x * (1.0 - x2 * (1.0 / 3.0 - x2 * 0.2))
                lx, ly, lz = ax + bx + cx, ay + by + cy, az + bz + cz
                r = 1.0 / math.sqrt(lx * lx + ly * ly + lz * lz)
                dx, dy, dz = lx * r - centroid[0, lane], ly * r - centroid[1, lane], lz * r - centroid[2, lane]
                y2 = 0.25 * (dx * dx + dy * dy + dz * dz)  # sin^2(theta / 2)
                theta2 = 4.0 * y2 * (1.0 + y2 * (1.0 / 3.0 + y2 * (8.0 / 45.0 + y2 * (4.0 / 35.0))))
                acc[lane] += theta2 * d_area
                worst[lane] = max(worst[lane], max(x * 100.0, y2 * 100.0))
        for lane in range(m):
            out[first + lane] = acc[lane] if worst[lane] < 1.0 else -1.0  # -1: redo exactly


@njit(cache=True)
def _vertices_from_sides(a: float, b: float, c: float, v1, v2, v3) -> bool:
    """A triangle with sides d12 = a, d23 = b, d31 = c (v1 at the pole); False if none."""
    sa, ca, sc, cc = math.sin(a), math.cos(a), math.sin(c), math.cos(c)
    if sa <= 0.0 or sc <= 0.0:
        return False
    cos_phi = (math.cos(b) - ca * cc) / (sa * sc)
    if cos_phi < -1.0 or cos_phi > 1.0:
        return False
    sin_phi = math.sqrt(1.0 - cos_phi * cos_phi)
    v1[0], v1[1], v1[2] = 0.0, 0.0, 1.0
    v2[0], v2[1], v2[2] = sa, 0.0, ca
    v3[0], v3[1], v3[2] = sc * cos_phi, sc * sin_phi, cc
    return True


@njit(cache=True)
def _polar_moment_jacobian(a: float, b: float, c: float, depth: int, work, out) -> None:
    """d(polar moment)/d(a, b, c) by central differences of the subdivision."""
    v1, v2, v3 = np.empty(3), np.empty(3), np.empty(3)
    h = 1e-6 * max(a, b, c)
    sides = np.array([a, b, c])
    for k in range(3):
        value = np.empty(2)
        ok = True
        for m in range(2):
            s = sides.copy()
            s[k] += h if m == 0 else -h
            if not _vertices_from_sides(s[0], s[1], s[2], v1, v2, v3):
                ok = False
                break
            value[m] = _polar_moment(v1, v2, v3, depth, work)
        out[k] = (value[0] - value[1]) / (2.0 * h) if ok else np.inf


@njit(cache=True, inline="always")
def _vertex_cosine(p, q, r) -> float:
    """Cosine of the spherical angle at p between the arcs toward q and toward r."""
    dq = p[0] * q[0] + p[1] * q[1] + p[2] * q[2]
    dr = p[0] * r[0] + p[1] * r[1] + p[2] * r[2]
    qx, qy, qz = q[0] - dq * p[0], q[1] - dq * p[1], q[2] - dq * p[2]  # tangent toward q
    rx, ry, rz = r[0] - dr * p[0], r[1] - dr * p[1], r[2] - dr * p[2]  # tangent toward r
    norm = math.sqrt((qx * qx + qy * qy + qz * qz) * (rx * rx + ry * ry + rz * rz))
    return (qx * rx + qy * ry + qz * rz) / norm if norm > 0.0 else 1.0


@njit(cache=True)
def _side_covariance(v1, v2, v3, s1: float, s2: float, s3: float, out) -> None:
    """Covariance of the sides (d12, d23, d31) from per-axis direction sigmas s_i [rad]:
    a star's error moves both sides meeting there, correlated by the vertex angle's cosine."""
    out[0, 0] = s1 * s1 + s2 * s2
    out[1, 1] = s2 * s2 + s3 * s3
    out[2, 2] = s3 * s3 + s1 * s1
    out[0, 1] = out[1, 0] = s2 * s2 * _vertex_cosine(v2, v1, v3)  # d12, d23 meet at star 2
    out[1, 2] = out[2, 1] = s3 * s3 * _vertex_cosine(v3, v2, v1)  # d23, d31 meet at star 3
    out[0, 2] = out[2, 0] = s1 * s1 * _vertex_cosine(v1, v3, v2)  # d31, d12 meet at star 1


@njit(cache=True)
def _tolerance(jac, cov, beta: float, floor: float) -> float:
    """beta * sqrt(H R H^T) plus the worst case of a `floor` error on every side."""
    var = 0.0
    worst = 0.0
    for i in range(3):
        worst += abs(jac[i])
        for j in range(3):
            var += jac[i] * cov[i, j] * jac[j]
    if not (var < np.inf) or not (worst < np.inf):
        return np.inf
    return beta * math.sqrt(max(var, 0.0)) + floor * worst


# ----------------------------------------------------------------------------------------
# Vectorized features (public).

@njit(cache=True)
def _sides_kernel(v1, v2, v3, out):
    for t in range(v1.shape[0]):
        out[t, 0] = _arc(v1[t], v2[t])
        out[t, 1] = _arc(v2[t], v3[t])
        out[t, 2] = _arc(v3[t], v1[t])


def triangle_sides(v1: np.ndarray, v2: np.ndarray, v3: np.ndarray) -> np.ndarray:
    """(T, 3) sides (d12, d23, d31) [rad] of triangles with unit-vector vertices (T, 3) each."""
    v1, v2, v3 = (np.ascontiguousarray(np.atleast_2d(v), dtype=float) for v in (v1, v2, v3))
    out = np.empty((v1.shape[0], 3))
    _sides_kernel(v1, v2, v3, out)
    return out


@njit(cache=True)
def _area_kernel(sides, out, jac):
    for t in range(sides.shape[0]):
        out[t] = _lhuilier_area(sides[t, 0], sides[t, 1], sides[t, 2])
        _lhuilier_jacobian(sides[t, 0], sides[t, 1], sides[t, 2], jac[t])


def spherical_area(sides: np.ndarray) -> np.ndarray:
    """Spherical area [sr] from (T, 3) sides [rad] (l'Huilier, eqs. 15-16)."""
    sides = np.ascontiguousarray(np.atleast_2d(sides), dtype=float)
    out, jac = np.empty(sides.shape[0]), np.empty((sides.shape[0], 3))
    _area_kernel(sides, out, jac)
    return out


def spherical_area_jacobian(sides: np.ndarray) -> np.ndarray:
    """(T, 3) dA/d(a, b, c) of the spherical area (eqs. 20-23)."""
    sides = np.ascontiguousarray(np.atleast_2d(sides), dtype=float)
    out, jac = np.empty(sides.shape[0]), np.empty((sides.shape[0], 3))
    _area_kernel(sides, out, jac)
    return jac


@njit(cache=True)
def _moment_kernel(v1, v2, v3, depth, out):
    work = moment_workspace(depth)
    for t in range(v1.shape[0]):
        out[t] = _polar_moment(v1[t], v2[t], v3[t], depth, work)


def spherical_polar_moment(v1: np.ndarray, v2: np.ndarray, v3: np.ndarray, depth: int = 3) -> np.ndarray:
    """Cole's spherical polar moment (eq. 25) [sr rad^2] by subdivision to `depth`."""
    if not (0 <= depth <= 10):
        raise ValueError(f"depth={depth} must be in [0, 10]")
    v1, v2, v3 = (np.ascontiguousarray(np.atleast_2d(v), dtype=float) for v in (v1, v2, v3))
    out = np.empty(v1.shape[0])
    _moment_kernel(v1, v2, v3, depth, out)
    return out


def spherical_polar_moment_fast(v1: np.ndarray, v2: np.ndarray, v3: np.ndarray, depth: int = 3) -> np.ndarray:
    """The same as the catalog build computes it: many triangles side by side with series for
    atan and asin (exact triangles beyond their range)."""
    v1, v2, v3 = (np.ascontiguousarray(np.atleast_2d(v), dtype=float) for v in (v1, v2, v3))
    n = v1.shape[0]
    vectors = np.concatenate([v1, v2, v3])
    stars = np.column_stack([np.arange(n), n + np.arange(n), 2 * n + np.arange(n)])
    out = np.empty((5, n))
    _catalog_features_kernel(vectors, stars, depth, *subdivision_tables(depth), *out)
    return out[1]


def planar_area(sides: np.ndarray) -> np.ndarray:
    """Toloei eq. 1: Heron's area [rad^2] of the planar triangle with the given sides."""
    a, b, c = np.atleast_2d(sides).T
    p = (a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c)
    return 0.25 * np.sqrt(np.maximum(p, 0.0))


def planar_polar_moment(sides: np.ndarray) -> np.ndarray:
    """Toloei eq. 2: I = A (a^2 + b^2 + c^2) / 36 [rad^4], the polar moment about the centroid."""
    sides = np.atleast_2d(sides)
    return planar_area(sides) * np.sum(sides**2, axis=1) / 36.0


@dataclass(frozen=True)
class FeatureSet:
    """Features of measured triangles with their match tolerances (beta sigma + floor):
    sides (T, 3) [rad], handedness (T,) sign of det[v1, v2, v3] (0: too flat to tell),
    side_tol (T, 3) [rad], area, area_tol, moment, moment_tol (T,); product, product_tol
    (T,): the side product a b c [rad^3], the third invariant of the shape besides area and
    moment (with them it fixes the triangle up to reflection), used to skip finalists before
    the vertex assignment."""

    sides: np.ndarray
    handedness: np.ndarray
    side_tol: np.ndarray
    area: np.ndarray
    area_tol: np.ndarray
    moment: np.ndarray
    moment_tol: np.ndarray
    product: np.ndarray
    product_tol: np.ndarray

    def __len__(self) -> int:
        return int(self.area.size)

    def take(self, index) -> "FeatureSet":
        """The features of the triangles `index` (an int or an index array)."""
        index = np.atleast_1d(index)
        return FeatureSet(*(np.ascontiguousarray(getattr(self, f)[index]) for f in
                            ("sides", "handedness", "side_tol", "area", "area_tol", "moment", "moment_tol",
                             "product", "product_tol")))


@njit(cache=True)
def _measured_kernel(rays, sigma, triples, spherical, depth, beta, floor,
                     sides, hand, side_tol, area, area_tol, moment, moment_tol, product, product_tol):
    work = moment_workspace(depth)
    cov = np.empty((3, 3))
    jac_a, jac_m = np.empty(3), np.empty(3)
    for t in range(triples.shape[0]):
        i, j, k = triples[t, 0], triples[t, 1], triples[t, 2]
        v1, v2, v3 = rays[i], rays[j], rays[k]
        a, b, c = _arc(v1, v2), _arc(v2, v3), _arc(v3, v1)
        sides[t, 0], sides[t, 1], sides[t, 2] = a, b, c
        _side_covariance(v1, v2, v3, sigma[i], sigma[j], sigma[k], cov)
        # Handedness, or 0 (undecided) for triangles so flat that noise could flip it.
        det = _det(v1, v2, v3)
        hand[t] = 0 if abs(det) <= beta * max(sigma[i], sigma[j], sigma[k]) * (a + b + c) else (1 if det > 0.0 else -1)
        pair_sigma = (math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1]), math.sqrt(cov[2, 2]))
        for m in range(3):
            side_tol[t, m] = beta * pair_sigma[m] + floor
        if spherical:
            area[t] = _lhuilier_area(a, b, c)
            _lhuilier_jacobian(a, b, c, jac_a)
            moment[t] = _polar_moment(v1, v2, v3, depth, work)
            _polar_moment_jacobian(a, b, c, depth, work, jac_m)
        else:
            area[t] = _heron_area(a, b, c)
            moment[t] = area[t] * (a * a + b * b + c * c) / 36.0
            _planar_jacobians(a, b, c, jac_a, jac_m)
        area_tol[t] = _tolerance(jac_a, cov, beta, floor)
        moment_tol[t] = _tolerance(jac_m, cov, beta, floor)
        product[t] = a * b * c
        jac_a[0], jac_a[1], jac_a[2] = b * c, c * a, a * b
        product_tol[t] = _tolerance(jac_a, cov, beta, floor)


def measured_features(rays: np.ndarray, sigma: np.ndarray, triples: np.ndarray, spherical: bool,
                      depth: int = 3, beta: float = 3.0, floor: float = 0.0) -> FeatureSet:
    """Features of spot triangles `triples` (T, 3) of indices into `rays` (N, 3) (sensor
    frame) with per-axis direction 1-sigma `sigma` (N,) [rad]; tolerances are beta sigma
    plus `floor` [rad] of model error on each side, propagated. spherical=True: Cole's area
    and polar moment (depth levels); False: Toloei's planar ones."""
    triples = np.ascontiguousarray(triples, dtype=np.int64).reshape(-1, 3)
    t = triples.shape[0]
    out = FeatureSet(np.empty((t, 3)), np.empty(t, np.int8), np.empty((t, 3)), *(np.empty(t) for _ in range(6)))
    _measured_kernel(np.ascontiguousarray(rays, dtype=float), np.ascontiguousarray(sigma, dtype=float), triples,
                     spherical, depth, float(beta), float(floor), out.sides, out.handedness, out.side_tol,
                     out.area, out.area_tol, out.moment, out.moment_tol, out.product, out.product_tol)
    return out


# ----------------------------------------------------------------------------------------
# Catalog triangle database.

@dataclass(frozen=True)
class TriangleConfig:
    """max_side_rad: longest side of a cataloged triangle (the field of view) [rad];
    moment_depth: subdivision levels of the spherical polar moment (Cole: 3);
    max_triangles: budget; if all guide stars give more triangles, stars are thinned;
    stars_per_cell: brightest stars kept per sky cell when thinning (the cell size is then the
    finest that fits the budget)."""

    max_side_rad: float = DEFAULT_MAX_SIDE_RAD
    moment_depth: int = 3
    max_triangles: int = 2_000_000
    stars_per_cell: int = 2

    def __post_init__(self) -> None:
        bad = []
        if not (0.0 < self.max_side_rad <= np.radians(60.0)):
            bad.append(f"max_side_rad={self.max_side_rad} must be in (0, 60 deg]")
        if not (0 <= self.moment_depth <= 6):
            bad.append(f"moment_depth={self.moment_depth} must be in [0, 6]")
        if not (1000 <= self.max_triangles <= 50_000_000):
            bad.append(f"max_triangles={self.max_triangles} must be in [1000, 5e7]")
        if not (1 <= self.stars_per_cell <= 1000):
            bad.append(f"stars_per_cell={self.stars_per_cell} must be in [1, 1000]")
        if bad:
            raise ValueError("invalid triangle config: " + "; ".join(bad))

    @staticmethod
    def for_database(database: StarDatabase, max_side_rad: float | None = None, **kwargs) -> "TriangleConfig":
        """Default for a pair database: sides up to its largest pair angle, at most
        DEFAULT_MAX_SIDE_RAD (8 deg). For Cole's 8 deg field that is the field itself; for
        the 15 deg camera, all Hp <= 6.5 stars with sides <= 8 deg (1.8 M triangles) beat the
        brightest stars with sides <= 15 deg under the same budget: a 15 deg field always holds
        small triangles of bright stars, and with many false stars (Toloei's scenes) the few
        real ones must all be in the catalog."""
        if max_side_rad is None:
            max_side_rad = min(database.config.max_pair_angle_rad, DEFAULT_MAX_SIDE_RAD)
        return TriangleConfig(max_side_rad=float(max_side_rad), **kwargs)

    def cache_key(self, database: StarDatabase) -> str:
        text = json.dumps({**asdict(self), "pairs": database.config.cache_key(),
                           "version": TRIANGLE_FORMAT_VERSION}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class FeatureIndex:
    """Catalog triangles ordered for one feature pair (area, polar moment).

    Rows are sorted by area and cut into blocks of `block` rows; within a block, rows are
    re-sorted by moment. An area window is then a run of blocks (found with a k-vector over
    the blocks' smallest areas), and in each block a binary search on the moment yields the
    finalists without scanning the window row by row. stars (T, 3): database star indices,
    ascending within a row; area, moment (T,) [sr or rad^2; sr rad^2 or rad^4]; product
    (T,): side product a b c [rad^3]; block_min, block_max (B,) area range of each block."""

    stars: np.ndarray
    area: np.ndarray
    moment: np.ndarray
    product: np.ndarray
    block: int
    block_min: np.ndarray
    block_max: np.ndarray
    kvector: KVector

    @staticmethod
    def build(stars: np.ndarray, area: np.ndarray, moment: np.ndarray, product: np.ndarray,
              block: int = 64) -> "FeatureIndex":
        by_area = np.argsort(area)
        area_sorted = area[by_area]
        # Within each block of `block` rows, by moment (the last block padded with +inf).
        padded = np.full(-(-area.size // block) * block, np.inf)
        padded[:area.size] = moment[by_area]
        within = np.argsort(padded.reshape(-1, block), axis=1, kind="stable")
        positions = (within + np.arange(0, padded.size, block)[:, None]).ravel()
        order = by_area[positions[positions < area.size]]
        starts = np.arange(0, area.size, block)
        block_min = area_sorted[starts]
        block_max = area_sorted[np.minimum(starts + block, area.size) - 1]
        return FeatureIndex(stars[order], area[order].astype(np.float32), moment[order].astype(np.float32),
                            product[order].astype(np.float32), block, block_min, block_max,
                            _compact_kvector(block_min))

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in (self.stars, self.area, self.moment, self.product, self.block_min,
                                          self.block_max, self.kvector.k)))

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}_stars": self.stars, f"{prefix}_area": self.area, f"{prefix}_moment": self.moment,
                f"{prefix}_product": self.product,
                f"{prefix}_block": np.array(self.block), f"{prefix}_block_min": self.block_min,
                f"{prefix}_block_max": self.block_max, f"{prefix}_k": self.kvector.k,
                f"{prefix}_line": np.array([self.kvector.slope, self.kvector.intercept])}

    @staticmethod
    def from_arrays(arrays: dict[str, np.ndarray], prefix: str, star_count: int) -> "FeatureIndex":
        """The index saved by `arrays`; ValueError when the arrays are not one this code wrote
        for a database of `star_count` stars (shapes, dtypes, star indices in range)."""
        stars, line = arrays[f"{prefix}_stars"], arrays[f"{prefix}_line"]
        rows = stars.shape[0] if stars.ndim == 2 else -1
        columns = [arrays[f"{prefix}_{name}"] for name in ("area", "moment", "product")]
        bounds = [arrays[f"{prefix}_{name}"] for name in ("block_min", "block_max", "k")]
        if (stars.ndim != 2 or stars.shape[1] != 3 or not np.issubdtype(stars.dtype, np.integer)
                or any(c.shape != (rows,) for c in columns) or line.shape != (2,)
                or len({b.shape for b in bounds}) != 1 or bounds[0].ndim != 1
                or (rows and (stars.min() < 0 or stars.max() >= star_count))):
            raise ValueError(f"cached {prefix} triangle index does not match the database")
        return FeatureIndex(arrays[f"{prefix}_stars"], arrays[f"{prefix}_area"], arrays[f"{prefix}_moment"],
                            arrays[f"{prefix}_product"], int(arrays[f"{prefix}_block"]), arrays[f"{prefix}_block_min"],
                            arrays[f"{prefix}_block_max"],
                            KVector(arrays[f"{prefix}_block_min"], arrays[f"{prefix}_k"], float(line[0]),
                                    float(line[1])))


@dataclass(frozen=True)
class TriangleDatabase:
    """Catalog triangles with both feature pairs: spherical (Cole: area [sr], polar moment
    [sr rad^2]) and planar (Toloei: area [rad^2], polar moment [rad^4]), each a FeatureIndex.
    guide_stars: database star indices used (after thinning); cells_per_face: thinning grid
    (0: all stars); build_seconds: time of the build [s]."""

    config: TriangleConfig
    spherical: FeatureIndex
    planar: FeatureIndex
    guide_stars: np.ndarray
    cells_per_face: int
    build_seconds: float = 0.0

    @property
    def triangle_count(self) -> int:
        return int(self.spherical.stars.shape[0])

    @property
    def nbytes(self) -> int:
        """Memory held by the arrays [bytes] (the cache file is about as large)."""
        return self.spherical.nbytes + self.planar.nbytes + int(self.guide_stars.nbytes)


def sky_cells(vectors: np.ndarray, cells_per_face: int) -> np.ndarray:
    """Cell id of each unit vector on an equal-angle cube-sphere grid with
    cells_per_face^2 cells on each of the six faces (cell areas within a factor ~1.4)."""
    vectors = np.asarray(vectors, dtype=float)
    axis = np.argmax(np.abs(vectors), axis=1)
    rows = np.arange(vectors.shape[0])
    major = vectors[rows, axis]
    face = 2 * axis + (major > 0)
    other1 = np.array([1, 0, 0])[axis]
    other2 = np.array([2, 2, 1])[axis]
    n = cells_per_face
    cell = []
    for other in (other1, other2):
        angle = np.arctan(vectors[rows, other] / np.abs(major))  # in [-pi/4, pi/4]
        cell.append(np.clip(np.floor((angle + np.pi / 4) / (np.pi / 2) * n), 0, n - 1).astype(np.int64))
    return (face * n + cell[0]) * n + cell[1]


def brightest_per_cell(vectors: np.ndarray, magnitude: np.ndarray, cells_per_face: int, per_cell: int) -> np.ndarray:
    """Indices (ascending) of the `per_cell` brightest stars of each sky cell."""
    cell = sky_cells(vectors, cells_per_face)
    order = np.lexsort((np.arange(cell.size), magnitude, cell))
    sorted_cell = cell[order]
    first = np.searchsorted(sorted_cell, sorted_cell, side="left")
    rank = np.arange(cell.size) - first
    return np.sort(order[rank < per_cell])


def _adjacency(database: StarDatabase, stars: np.ndarray, max_side: float) -> tuple[np.ndarray, np.ndarray]:
    """CSR of 'later' neighbours among `stars` (positions into `stars`): j > i and the pair's
    angle <= max_side. Columns ascending."""
    pair_a, pair_b = database.pairs_in_range(0.0, max_side)
    position = np.full(database.star_count, -1, np.int64)
    position[stars] = np.arange(stars.size)
    a, b = position[pair_a], position[pair_b]
    keep = (a >= 0) & (b >= 0)
    a, b = a[keep], b[keep]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((hi, lo))
    lo, hi = lo[order], hi[order]
    indptr = np.zeros(stars.size + 1, np.int64)
    np.cumsum(np.bincount(lo, minlength=stars.size), out=indptr[1:])
    return indptr, hi.astype(np.int32)


@njit(cache=True)
def _triangles_kernel(indptr, indices, out):
    """Count (out of size 0) or list the triangles i < j < k of the graph: every j, k > i
    adjacent to i with k adjacent to j."""
    n = indptr.size - 1
    mark = np.zeros(n, np.bool_)
    count = 0
    fill = out.shape[0] > 0
    for i in range(n):
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            for q in range(indptr[j], indptr[j + 1]):
                mark[indices[q]] = True
            for p2 in range(p + 1, indptr[i + 1]):
                k = indices[p2]
                if mark[k]:
                    if fill:
                        out[count, 0], out[count, 1], out[count, 2] = i, j, k
                    count += 1
            for q in range(indptr[j], indptr[j + 1]):
                mark[indices[q]] = False
    return count


@njit(cache=True, parallel=True)
def _catalog_features_kernel(vectors, stars, depth, ops, leaves, sph_area, sph_moment, pl_area, pl_moment, product):
    n = stars.shape[0]
    chunk = 64 * _LANES
    for c in numba.prange((n + chunk - 1) // chunk):
        start, stop = c * chunk, min(n, (c + 1) * chunk)
        vert = np.empty((3 + ops.shape[0], 3, _LANES))
        _polar_moment_lanes(vectors, stars, start, stop, ops, leaves, vert, np.empty((3, _LANES)),
                            np.empty(_LANES), np.empty(_LANES), sph_moment)
        work = moment_workspace(depth)
        for t in range(start, stop):
            v1, v2, v3 = vectors[stars[t, 0]], vectors[stars[t, 1]], vectors[stars[t, 2]]
            a, b, cc = _arc(v1, v2), _arc(v2, v3), _arc(v3, v1)
            sph_area[t] = _lhuilier_area(a, b, cc)
            if sph_moment[t] < 0.0:
                sph_moment[t] = _polar_moment(v1, v2, v3, depth, work)
            pl_area[t] = _heron_area(a, b, cc)
            pl_moment[t] = pl_area[t] * (a * a + b * b + cc * cc) / 36.0
            product[t] = a * b * cc


def _count_triangles(database: StarDatabase, stars: np.ndarray, max_side: float) -> int:
    indptr, indices = _adjacency(database, stars, max_side)
    return int(_triangles_kernel(indptr, indices, np.zeros((0, 3), np.int64)))


def select_guide_stars(database: StarDatabase, config: TriangleConfig) -> tuple[np.ndarray, int]:
    """All database stars if their triangles fit the budget, else the brightest
    `stars_per_cell` per cell of the finest grid that fits: (star indices, cells_per_face).
    The grid is first guessed from triangles ~ stars^3, then stepped to the finest that fits."""
    everything = np.arange(database.star_count)
    total = _count_triangles(database, everything, config.max_side_rad)
    if total <= config.max_triangles:
        return everything, 0

    def thinned(n: int) -> np.ndarray:
        return brightest_per_cell(database.vectors, database.magnitude, n, config.stars_per_cell)

    def fits(n: int) -> bool:
        return _count_triangles(database, thinned(n), config.max_side_rad) <= config.max_triangles

    target = everything.size * (config.max_triangles / total) ** (1.0 / 3.0)
    n = 1
    while n < 256 and thinned(n + 1).size <= target:
        n += 1
    while n > 1 and not fits(n):
        n -= 1
    while n < 256 and fits(n + 1):
        n += 1
    return thinned(n), n


def _smallest_uint(limit: int):
    return np.uint16 if limit < 2**16 else np.int32


def build_triangle_database(database: StarDatabase, config: TriangleConfig) -> TriangleDatabase:
    started = time.perf_counter()
    guide, cells = select_guide_stars(database, config)
    indptr, indices = _adjacency(database, guide, config.max_side_rad)
    count = _triangles_kernel(indptr, indices, np.zeros((0, 3), np.int64))
    local = np.empty((count, 3), np.int64)
    _triangles_kernel(indptr, indices, local)
    stars = guide[local].astype(_smallest_uint(database.star_count))  # guide ascending: rows stay ascending
    sph_area, sph_moment, pl_area, pl_moment, product = (np.empty(count) for _ in range(5))
    _catalog_features_kernel(np.ascontiguousarray(database.vectors, dtype=float), stars, config.moment_depth,
                             *subdivision_tables(config.moment_depth), sph_area, sph_moment, pl_area, pl_moment,
                             product)
    return TriangleDatabase(config=config, spherical=FeatureIndex.build(stars, sph_area, sph_moment, product),
                            planar=FeatureIndex.build(stars, pl_area, pl_moment, product),
                            guide_stars=guide.astype(np.int32),
                            cells_per_face=cells, build_seconds=time.perf_counter() - started)


def _compact_kvector(sorted_values: np.ndarray) -> KVector:
    kv = KVector.build(sorted_values)
    return KVector(kv.sorted_values, kv.k.astype(np.int32), kv.slope, kv.intercept)


_MEMO: dict[Path, TriangleDatabase] = {}


def triangle_cache_path(database: StarDatabase, config: TriangleConfig, directory: Path | None = None) -> Path:
    return (directory or cache_dir()) / f"triangles_{config.cache_key(database)}.npz"


def load_or_build_triangles(database: StarDatabase, config: TriangleConfig | None = None,
                            directory: Path | None = None) -> TriangleDatabase:
    """The triangle database of `database` and `config` (default: for_database), loaded from
    the checksum-validated cache or built and cached; kept in memory per cache file."""
    config = config or TriangleConfig.for_database(database)
    path = triangle_cache_path(database, config, directory)
    if path in _MEMO and path.is_file():
        return _MEMO[path]
    arrays = load_validated_npz(path)
    triangles = None
    if arrays is not None:
        try:
            guide_stars = arrays["guide_stars"]
            if guide_stars.ndim != 1 or (guide_stars.size and (guide_stars.min() < 0
                                                                or guide_stars.max() >= database.star_count)):
                raise ValueError("cached guide stars do not match the database")
            triangles = TriangleDatabase(
                config=config, spherical=FeatureIndex.from_arrays(arrays, "spherical", database.star_count),
                planar=FeatureIndex.from_arrays(arrays, "planar", database.star_count), guide_stars=guide_stars,
                cells_per_face=int(arrays["cells_per_face"]), build_seconds=float(arrays["build_seconds"]))
        except (KeyError, ValueError, TypeError):
            triangles = None  # another layout, or not written for this database: rebuild
    if triangles is None:
        triangles = build_triangle_database(database, config)
        save_validated_npz(path, {
            **triangles.spherical.arrays("spherical"), **triangles.planar.arrays("planar"),
            "guide_stars": triangles.guide_stars, "cells_per_face": np.array(triangles.cells_per_face),
            "build_seconds": np.array(triangles.build_seconds)})
    _MEMO[path] = triangles
    return triangles


# ----------------------------------------------------------------------------------------
# Matching measured triangles against the catalog.

@njit(cache=True)
def _kvector_window(k, slope, intercept, first, last, lo, hi):
    n = k.size
    if hi < lo or hi < first or lo > last:
        return 0, 0
    j_lo = int(math.floor((lo - intercept) / slope))
    j_hi = int(math.ceil((hi - intercept) / slope))
    start = k[min(j_lo - 1, n - 1)] if j_lo >= 1 else 0
    stop = k[j_hi] if 0 <= j_hi < n else n
    return start, stop


# Vertex assignments (catalog vertex of measured vertex 1, 2, 3): three even, three odd.
_PERMUTATIONS = np.array([[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 1], [2, 1, 0], [1, 0, 2]], np.int64)


@njit(cache=True, inline="always")
def _chord2(vectors, i, j) -> float:
    """Squared chord between rows i and j of `vectors` (indexing, not views: views cost)."""
    dx, dy, dz = vectors[i, 0] - vectors[j, 0], vectors[i, 1] - vectors[j, 1], vectors[i, 2] - vectors[j, 2]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, inline="always")
def _det_rows(vectors, i, j, k) -> float:
    """Triple product of rows i, j, k of `vectors`."""
    return (vectors[i, 0] * (vectors[j, 1] * vectors[k, 2] - vectors[j, 2] * vectors[k, 1])
            + vectors[i, 1] * (vectors[j, 2] * vectors[k, 0] - vectors[j, 0] * vectors[k, 2])
            + vectors[i, 2] * (vectors[j, 0] * vectors[k, 1] - vectors[j, 1] * vectors[k, 0]))


@njit(cache=True, inline="always")
def _fits_any(d2, lo2, hi2) -> bool:
    return (lo2[0] <= d2 <= hi2[0]) or (lo2[1] <= d2 <= hi2[1]) or (lo2[2] <= d2 <= hi2[2])


@njit(cache=True)
def _match_kernel(area, area_tol, moment, moment_tol, product, product_tol, sides, side_tol, hand, cap, check_sides,
                  cat_area, cat_moment, cat_product, tri_stars, block, block_min, block_max, k, slope, intercept,
                  vectors, perms, out_query, out_stars, n_area, n_final):
    """For every measured triangle q: catalog rows with area within area_tol and moment within
    moment_tol (blocks by k-vector, rows by binary search on the moment within each block);
    each vertex assignment whose three sides agree within side_tol (if check_sides) and
    whose handedness agrees is emitted as (q, star of vertex 1, 2, 3). More than `cap`
    assignments: the triangle is ambiguous and emits nothing (n_final = -1). Sides are
    compared as squared chords (monotonic in the angle)."""
    rows = 0
    n_rows = cat_area.size
    n_blocks = block_min.size
    verts = np.empty(3, np.int64)
    lo2, hi2 = np.empty(3), np.empty(3)
    pair_d2 = np.empty((3, 3))
    for q in range(area.size):
        lo, hi = area[q] - area_tol[q], area[q] + area_tol[q]
        m_lo, m_hi = moment[q] - moment_tol[q], moment[q] + moment_tol[q]
        for m in range(3):
            lo2[m] = (2.0 * math.sin(0.5 * max(sides[q, m] - side_tol[q, m], 0.0))) ** 2
            hi2[m] = (2.0 * math.sin(0.5 * min(sides[q, m] + side_tol[q, m], math.pi))) ** 2
        # Blocks starting inside [lo, hi], plus the one before (it may reach into the window).
        b_start, b_stop = _kvector_window(k, slope, intercept, block_min[0], block_min[n_blocks - 1], lo, hi)
        if b_start == b_stop:
            b_start = b_stop = np.searchsorted(block_min, lo)
        if b_start > 0 and block_max[b_start - 1] >= lo:
            b_start -= 1
        begin = rows
        in_area = 0
        final = 0
        for b in range(b_start, b_stop):
            r0, r1 = b * block, min((b + 1) * block, n_rows)
            whole = block_min[b] >= lo and block_max[b] <= hi
            if whole:
                in_area += r1 - r0
            else:
                for t in range(r0, r1):
                    in_area += (cat_area[t] >= lo) & (cat_area[t] <= hi)
            f0 = r0 + np.searchsorted(cat_moment[r0:r1], m_lo)
            f1 = r0 + np.searchsorted(cat_moment[r0:r1], m_hi, side="right")
            for t in range(f0, f1):
                if not whole and (cat_area[t] < lo or cat_area[t] > hi):
                    continue
                final += 1
                if check_sides and abs(cat_product[t] - product[q]) > product_tol[q]:
                    continue  # not congruent: skip the vertex assignment
                for v in range(3):
                    verts[v] = tri_stars[t, v]
                d01 = _chord2(vectors, verts[0], verts[1])
                d12 = _chord2(vectors, verts[1], verts[2])
                d20 = _chord2(vectors, verts[2], verts[0])
                if check_sides and not (_fits_any(d01, lo2, hi2) and _fits_any(d12, lo2, hi2)
                                        and _fits_any(d20, lo2, hi2)):
                    continue  # some catalog side matches no measured side: no assignment can
                pair_d2[0, 1] = pair_d2[1, 0] = d01
                pair_d2[1, 2] = pair_d2[2, 1] = d12
                pair_d2[0, 2] = pair_d2[2, 0] = d20
                right_handed = _det_rows(vectors, verts[0], verts[1], verts[2]) > 0.0
                for p in range(perms.shape[0]):
                    a, b2, c = perms[p, 0], perms[p, 1], perms[p, 2]
                    if hand[q] != 0 and (right_handed == (p < 3)) != (hand[q] > 0):
                        continue  # mirror image (odd permutations flip the handedness)
                    if check_sides and not (lo2[0] <= pair_d2[a, b2] <= hi2[0] and lo2[1] <= pair_d2[b2, c] <= hi2[1]
                                            and lo2[2] <= pair_d2[c, a] <= hi2[2]):
                        continue
                    if rows < out_query.size:
                        out_query[rows] = q
                        out_stars[rows, 0], out_stars[rows, 1], out_stars[rows, 2] = verts[a], verts[b2], verts[c]
                    rows += 1
        n_area[q] = in_area
        n_final[q] = final
        if rows - begin > cap or rows > out_query.size:
            rows = begin
            n_final[q] = -1
    return rows


@dataclass(frozen=True)
class TriangleMatches:
    """query (M,): index of the measured triangle; stars (M, 3): database stars assigned to its
    vertices 1, 2, 3. area_candidates, finalists (Q,): catalog triangles within the area
    window, and also within the moment window (-1: more than the cap of assignments)."""

    query: np.ndarray
    stars: np.ndarray
    area_candidates: np.ndarray
    finalists: np.ndarray


def match_triangles(triangles: TriangleDatabase, database: StarDatabase, features: FeatureSet, spherical: bool,
                    cap: int, check_sides: bool = True) -> TriangleMatches:
    """Catalog matches of measured triangles: area window (k-vector), then polar moment, then
    the vertex assignments whose sides agree (all that keep the handedness if not
    check_sides), with the handedness (mirror) test."""
    q = len(features)
    index = triangles.spherical if spherical else triangles.planar
    capacity = max(min(q * (cap + 6), 1 << 20), 16)
    out_query, out_stars = np.empty(capacity, np.int64), np.empty((capacity, 3), np.int64)
    n_area, n_final = np.zeros(q, np.int64), np.zeros(q, np.int64)
    kv = index.kvector
    rows = _match_kernel(features.area, features.area_tol, features.moment, features.moment_tol, features.product,
                         features.product_tol, features.sides, features.side_tol, features.handedness, cap,
                         check_sides, index.area, index.moment, index.product, index.stars, index.block,
                         index.block_min, index.block_max, kv.k, kv.slope, kv.intercept, database.vectors,
                         _PERMUTATIONS, out_query, out_stars, n_area, n_final)
    return TriangleMatches(out_query[:rows], out_stars[:rows], n_area, n_final)


def warm_up(triangles: TriangleDatabase, database: StarDatabase) -> None:
    """Compile (or load from numba's cache) the matching kernels now, not in the first frame."""
    rays = np.array([[0.0, 0.0, 1.0], [0.01, 0.0, 1.0], [0.0, 0.01, 1.0]])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    triple = np.array([[0, 1, 2]])
    for spherical in (True, False):
        features = measured_features(rays, np.full(3, 1e-5), triple, spherical, triangles.config.moment_depth)
        match_triangles(triangles, database, features.take(0), spherical, cap=1)
