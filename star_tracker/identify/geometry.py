# SPDX-License-Identifier: Apache-2.0
"""
Geometry of unit vectors shared by the identification algorithms.

Directions are unit 3-vectors (sensor frame or ICRS, the same frame on both sides); angles
are radians. The angle between two unit vectors is taken from their chord, 2 asin(|u - v| / 2),
which stays exact at the small angles of a star field (acos(u . v) loses half the digits there).
The handedness of a triple is the sign of its triple product u . (v x w) (van Bezooijen's
mirror test compares it between spots and stars). The scalar forms compile with numba (kernels
inline them); the vectorised ones are numpy. Also Mortari's pyramid order of spot triples.
"""
from __future__ import annotations

import math
from functools import lru_cache
from typing import Iterator

import numpy as np
from numba import njit


def chord_angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between unit vectors (..., 3) [rad]; the chord form stays exact for small angles."""
    return 2.0 * np.arcsin(np.clip(0.5 * np.linalg.norm(u - v, axis=-1), 0.0, 1.0))


def triple_products(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Triple products u . (v x w) of rows of (T, 3) arrays: positive for right-handed triples."""
    return np.einsum("ni,ni->n", u, np.cross(v, w))


@lru_cache(maxsize=64)
def pyramid_triangles(n: int) -> np.ndarray:
    """
    (T, 3) Mortari's pyramid order of the index triples i < j < k < n (read-only, shared).

    The index gaps (j - i, k - j) grow slowest, so the search leaves a false spot behind as
    fast as it can. Built once per n: every lost-in-space solve starts from it (building it
    was a third of the search's time).
    """
    triangles = pyramid_rows(n, math.comb(n, 3) if n >= 3 else 0)
    triangles.flags.writeable = False
    return triangles


@njit(cache=True)
def pyramid_rows(n, count):
    """Return the first `count` rows of pyramid_triangles(n) (compiled: the one-call solve builds its first batch)."""
    rows = np.empty((count, 3), np.int64)
    t = 0
    for dj in range(1, n - 1):
        for dk in range(1, n - dj):
            for i in range(0, n - dj - dk):
                if t == count:
                    return rows
                rows[t, 0], rows[t, 1], rows[t, 2] = i, i + dj, i + dj + dk
                t += 1
    return rows[:t]


def pyramid_order(n: int) -> Iterator[tuple[int, int, int]]:
    """Return the triples of `pyramid_triangles` one by one, as ints."""
    for i, j, k in pyramid_triangles(n).tolist():
        yield i, j, k


@njit(cache=True, inline="always")
def angle_between(u, v) -> float:
    """Angle between unit vectors [rad]: 2 asin(|u - v| / 2), accurate at small angles."""
    dx, dy, dz = u[0] - v[0], u[1] - v[1], u[2] - v[2]
    return 2.0 * math.asin(min(1.0, 0.5 * math.sqrt(dx * dx + dy * dy + dz * dz)))


@njit(cache=True, inline="always")
def triple_product(u, v, w) -> float:
    """Triple product u . (v x w): positive for a counter-clockwise (right-handed) triple."""
    return (u[0] * (v[1] * w[2] - v[2] * w[1]) + u[1] * (v[2] * w[0] - v[0] * w[2])
            + u[2] * (v[0] * w[1] - v[1] * w[0]))


@njit(cache=True, inline="always")
def chord2_rows(vectors, i, j) -> float:
    """Squared chord between rows i and j of `vectors` (indexing, not views: views cost)."""
    dx, dy, dz = vectors[i, 0] - vectors[j, 0], vectors[i, 1] - vectors[j, 1], vectors[i, 2] - vectors[j, 2]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, inline="always")
def triple_product_rows(vectors, i, j, k) -> float:
    """Triple product of rows i, j, k of `vectors`."""
    return (vectors[i, 0] * (vectors[j, 1] * vectors[k, 2] - vectors[j, 2] * vectors[k, 1])
            + vectors[i, 1] * (vectors[j, 2] * vectors[k, 0] - vectors[j, 0] * vectors[k, 2])
            + vectors[i, 2] * (vectors[j, 0] * vectors[k, 1] - vectors[j, 1] * vectors[k, 0]))
