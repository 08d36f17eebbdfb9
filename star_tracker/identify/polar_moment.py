# SPDX-License-Identifier: Apache-2.0
"""
Cole's spherical polar moment of a star triangle (eq. 25), I_p = sum theta^2 dA about the triangle's centroid.

By recursive subdivision into 4^depth sub-triangles (the thesis uses depth 3) [sr rad^2];
one triangle at a time (exact), or many side by side with series for atan and asin (the
catalog build), and its derivative in the sides by central differences of the same
subdivision. The thesis bounds the moment's sigma by simulation (a line above the worst
case); the derivative here follows each triangle's shape. Vertices are unit 3-vectors.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit


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
    """Scratch buffer for `polar_moment` at `depth`."""
    return np.empty((2, 4**depth, 9))


@njit(cache=True)
def polar_moment(v1, v2, v3, depth: int, work) -> float:
    """
    Cole's spherical polar moment (eq. 25).

    Split the triangle into four at its (normalized) edge midpoints, `depth` times (the
    children tile the parent exactly), and sum over the 4^depth leaves the leaf area dA
    times the squared arc theta from the leaf centroid to the triangle centroid; centroids
    are normalized vertex sums. `work` is moment_workspace(depth). (Indexing, not slicing:
    array views cost here.)
    """
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
            a, b, c = (ax, ay, az), (bx, by, bz), (cx, cy, cz)
            mab, mbc, mca = (mabx, maby, mabz), (mbcx, mbcy, mbcz), (mcax, mcay, mcaz)
            _put(work, nxt, o, a, mab, mca)
            _put(work, nxt, o + 1, b, mbc, mab)
            _put(work, nxt, o + 2, c, mca, mbc)
            _put(work, nxt, o + 3, mab, mbc, mca)
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
def _put(work, level, row, a, b, c) -> None:
    """Store the sub-triangle with vertices a, b, c ((x, y, z) tuples) at work[level, row]."""
    work[level, row, 0], work[level, row, 1], work[level, row, 2] = a[0], a[1], a[2]
    work[level, row, 3], work[level, row, 4], work[level, row, 5] = b[0], b[1], b[2]
    work[level, row, 6], work[level, row, 7], work[level, row, 8] = c[0], c[1], c[2]


class SubdivisionTables(NamedTuple):
    """
    The subdivision of `polar_moment` over a shared vertex list (corners 0, 1, 2).

    Ops (V, 2), vertex 3 + o is the normalized sum of vertices ops[o]; leaves (4^depth, 3),
    the vertex indices of the final sub-triangles.
    """

    ops: np.ndarray
    leaves: np.ndarray


class LaneScratch(NamedTuple):
    """
    Work arrays of `polar_moment_lanes`.

    Vert (3 + V, 3, LANES) subdivision vertices, centroid (3, LANES), acc and worst (LANES,)
    per-lane sums and series-range checks.
    """

    vert: np.ndarray
    centroid: np.ndarray
    acc: np.ndarray
    worst: np.ndarray


def subdivision_tables(depth: int) -> SubdivisionTables:
    """
    Return the subdivision of `polar_moment` as index tables over a shared vertex list (corners 0, 1, 2).

    Ops (V, 2), vertex 3 + o is the normalized sum of vertices ops[o] (each edge midpoint
    once); leaves (4^depth, 3), the vertex indices of the final sub-triangles.
    """
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
    return SubdivisionTables(np.array(ops, np.int64).reshape(-1, 2), np.array(triangles, np.int64))


LANES = 16  # triangles processed side by side (SIMD across triangles)


@njit(cache=True)
def lane_scratch(tables) -> LaneScratch:
    """Fresh work arrays of `polar_moment_lanes` for SubdivisionTables `tables`."""
    return LaneScratch(np.empty((3 + tables.ops.shape[0], 3, LANES)), np.empty((3, LANES)), np.empty(LANES),
                       np.empty(LANES))


@njit(cache=True, fastmath=True)
def polar_moment_lanes(vectors, stars, start, stop, tables, scratch, out) -> None:
    """
    `polar_moment` for catalog triangles stars[start:stop] (rows of indices into `vectors`).

    LANES at a time so the arithmetic vectorizes: atan and asin become their series, good to
    ~1e-9 while leaves have tan(dA/2) < 0.01 and lie within 0.2 rad of the centroid; out =
    -1 marks triangles beyond that (sides > ~20 deg) for an exact redo. `tables`:
    SubdivisionTables; `scratch`: lane_scratch(tables).
    """
    ops, leaves = tables.ops, tables.leaves
    vert, centroid, acc, worst = scratch.vert, scratch.centroid, scratch.acc, scratch.worst
    for first in range(start, stop, LANES):
        m = min(LANES, stop - first)
        for lane in range(LANES):
            t = first + lane if lane < m else first
            for corner in range(3):
                for k in range(3):
                    vert[corner, k, lane] = vectors[stars[t, corner], k]
        for lane in range(LANES):
            x = vert[0, 0, lane] + vert[1, 0, lane] + vert[2, 0, lane]
            y = vert[0, 1, lane] + vert[1, 1, lane] + vert[2, 1, lane]
            z = vert[0, 2, lane] + vert[1, 2, lane] + vert[2, 2, lane]
            r = 1.0 / math.sqrt(x * x + y * y + z * z)
            centroid[0, lane], centroid[1, lane], centroid[2, lane] = x * r, y * r, z * r
        for o in range(ops.shape[0]):
            p, q = ops[o, 0], ops[o, 1]
            for lane in range(LANES):
                x = vert[p, 0, lane] + vert[q, 0, lane]
                y = vert[p, 1, lane] + vert[q, 1, lane]
                z = vert[p, 2, lane] + vert[q, 2, lane]
                r = 1.0 / math.sqrt(x * x + y * y + z * z)
                vert[3 + o, 0, lane], vert[3 + o, 1, lane], vert[3 + o, 2, lane] = x * r, y * r, z * r
        acc[:] = 0.0
        worst[:] = 0.0
        for f in range(leaves.shape[0]):
            i, j, k = leaves[f, 0], leaves[f, 1], leaves[f, 2]
            for lane in range(LANES):
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
    """Return a triangle with sides d12 = a, d23 = b, d31 = c (v1 at the pole); False if none."""
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
def polar_moment_jacobian(a: float, b: float, c: float, depth: int, work, out) -> None:
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
            value[m] = polar_moment(v1, v2, v3, depth, work)
        out[k] = (value[0] - value[1]) / (2.0 * h) if ok else np.inf
