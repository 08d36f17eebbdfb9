# SPDX-License-Identifier: Apache-2.0
"""
Matching measured star triangles against the catalog triangle database.

The area window by k-vector, the polar moment window by binary search per block, then the
vertex assignments whose sides agree and whose handedness is the spots' (mirror test).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .database import StarDatabase
from .geometry import chord2_rows, triple_product_rows
from .kvector import kvector_window
from .triangle_database import TriangleDatabase
from .triangle_features import FeatureSet, measured_features


# Vertex assignments (catalog vertex of measured vertex 1, 2, 3): three even, three odd.
_PERMUTATIONS = np.array([[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 1], [2, 1, 0], [1, 0, 2]], np.int64)


@njit(cache=True, inline="always")
def _fits_any(d2, lo2, hi2) -> bool:
    return (lo2[0] <= d2 <= hi2[0]) or (lo2[1] <= d2 <= hi2[1]) or (lo2[2] <= d2 <= hi2[2])


@njit(cache=True)
def _match_kernel(features, index, vectors, cap, check_sides, out):
    """
    For every measured triangle q.

    Catalog rows with area within area_tol and moment within moment_tol (blocks by k-vector,
    rows by binary search on the moment within each block); each vertex assignment whose three
    sides agree within side_tol (if check_sides) and whose handedness agrees is emitted as (q,
    star of vertex 1, 2, 3). More than `cap` assignments: the triangle is ambiguous and emits
    nothing (n_final = -1). Sides are compared as squared chords (monotonic in the angle).
    features: FeatureSet; index: FeatureIndex; out: TriangleMatches with room for the rows;
    returns how many were emitted.
    """
    area, area_tol, moment, moment_tol = features.area, features.area_tol, features.moment, features.moment_tol
    product, product_tol, sides, side_tol = features.product, features.product_tol, features.sides, features.side_tol
    hand = features.handedness
    cat_area, cat_moment, cat_product, tri_stars = index.area, index.moment, index.product, index.stars
    block, block_min, block_max = index.block, index.block_min, index.block_max
    k, slope, intercept = index.kvector.k, index.kvector.slope, index.kvector.intercept
    out_query, out_stars, n_area, n_final = out.query, out.stars, out.area_candidates, out.finalists
    perms = _PERMUTATIONS
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
        b_start, b_stop = kvector_window(k, slope, intercept, block_min[0], block_min[n_blocks - 1], lo, hi)
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
                d01 = chord2_rows(vectors, verts[0], verts[1])
                d12 = chord2_rows(vectors, verts[1], verts[2])
                d20 = chord2_rows(vectors, verts[2], verts[0])
                if check_sides and not (_fits_any(d01, lo2, hi2) and _fits_any(d12, lo2, hi2)
                                        and _fits_any(d20, lo2, hi2)):
                    continue  # some catalog side matches no measured side: no assignment can
                pair_d2[0, 1] = pair_d2[1, 0] = d01
                pair_d2[1, 2] = pair_d2[2, 1] = d12
                pair_d2[0, 2] = pair_d2[2, 0] = d20
                right_handed = triple_product_rows(vectors, verts[0], verts[1], verts[2]) > 0.0
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


class TriangleMatches(NamedTuple):
    """
    query (M,): index of the measured triangle; stars (M, 3): database stars assigned to its vertices 1, 2, 3.

    area_candidates, finalists (Q,): catalog triangles within the area window, and also within
    the moment window (-1: more than the cap of assignments). The kernel fills one with room
    for M rows, of which match_triangles keeps those emitted.
    """

    query: np.ndarray
    stars: np.ndarray
    area_candidates: np.ndarray
    finalists: np.ndarray


def match_triangles(triangles: TriangleDatabase, database: StarDatabase, features: FeatureSet, spherical: bool,
                    cap: int, check_sides: bool = True) -> TriangleMatches:
    """
    Catalog matches of measured triangles.

    Area window (k-vector), then polar moment, then the vertex assignments whose sides agree
    (all that keep the handedness if not check_sides), with the handedness (mirror) test.
    """
    q = features.triangle_count
    index = triangles.spherical if spherical else triangles.planar
    capacity = max(min(q * (cap + 6), 1 << 20), 16)
    out = TriangleMatches(np.empty(capacity, np.int64), np.empty((capacity, 3), np.int64), np.zeros(q, np.int64),
                          np.zeros(q, np.int64))
    rows = _match_kernel(features, index, database.vectors, cap, check_sides, out)
    return out._replace(query=out.query[:rows], stars=out.stars[:rows])


def warm_up(triangles: TriangleDatabase, database: StarDatabase) -> None:
    """Compile (or load from numba's cache) the matching kernels now, not in the first frame."""
    rays = np.array([[0.0, 0.0, 1.0], [0.01, 0.0, 1.0], [0.0, 0.01, 1.0]])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    triple = np.array([[0, 1, 2]])
    for spherical in (True, False):
        features = measured_features(rays, np.full(3, 1e-5), triple, spherical, triangles.config.moment_depth)
        match_triangles(triangles, database, features.take(0), spherical, cap=1)
