"""Geometry of unit vectors shared by the identification algorithms.

Directions are unit 3-vectors (sensor frame or ICRS, the same frame on both sides); angles
are radians. The angle between two unit vectors is taken from their chord, 2 asin(|u - v| / 2),
which stays exact at the small angles of a star field (acos(u . v) loses half the digits there).
The scalar forms compile with numba (kernels inline them).
"""
from __future__ import annotations

import math

from numba import njit


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
