# SPDX-License-Identifier: Apache-2.0
"""
Attitude-independent shape invariants of a star triangle and their 1-sigma tolerances.

Side lengths are the inter-star angles a = d12, b = d23, c = d31 [rad].

* spherical (Cole & Crassidis 2006, Cole's thesis): the area A from the spherical excess,
  l'Huilier's formula (eqs. 15-16), with its analytic derivative (eqs. 17-24); the polar
  moment is in `polar_moment`;
* planar (Toloei et al. 2014): the area of the triangle with side lengths a, b, c by Heron's
  formula with s = (a+b+c)/2 (eq. 1) and the polar moment I = A (a^2+b^2+c^2)/36 (eq. 2).

Areas are [sr] (spherical) or [rad^2] (planar), polar moments [sr rad^2] or [rad^4].

Uncertainties: every feature F(a, b, c) is linearized in the three sides,
sigma_F^2 = H R H^T with H = dF/d(a, b, c) (eq. 19). Cole's eq. 24 takes the sides as
independent; here R is the sides' actual covariance: star i's direction error (1-sigma
s_i per axis) moves both sides meeting at it, so var(d12) = s_1^2 + s_2^2 and
cov(d12, d31) = s_1^2 cos(angle at star 1). All functions compile with numba.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def lhuilier_area(a: float, b: float, c: float) -> float:
    """Spherical area from the sides (eqs. 15-16) [sr]; 0 for degenerate triangles."""
    s = 0.5 * (a + b + c)
    t = math.tan(0.5 * s) * math.tan(0.5 * (s - a)) * math.tan(0.5 * (s - b)) * math.tan(0.5 * (s - c))
    return 4.0 * math.atan(math.sqrt(t)) if t > 0.0 else 0.0


@njit(cache=True)
def lhuilier_jacobian(a: float, b: float, c: float, out) -> None:
    """
    Return dA/d(a, b, c) of the spherical area (eqs. 20-23).

    The sign follows from differentiating z^2; Cole's leading minus does not affect H H^T.
    """
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
def heron_area(a: float, b: float, c: float) -> float:
    """Planar area of the triangle with sides a, b, c (Heron, Toloei eq. 1) [rad^2]."""
    p = (a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c)
    return 0.25 * math.sqrt(p) if p > 0.0 else 0.0


@njit(cache=True)
def planar_jacobians(a: float, b: float, c: float, d_area, d_moment) -> None:
    """d(area)/d(a, b, c) and d(moment)/d(a, b, c) of Toloei's eqs. 1-2."""
    area = heron_area(a, b, c)
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
def side_covariance(v1, v2, v3, s1: float, s2: float, s3: float, out) -> None:
    """
    Covariance of the sides (d12, d23, d31) from per-axis direction sigmas s_i [rad].

    A star's error moves both sides meeting there, correlated by the vertex angle's cosine.
    """
    out[0, 0] = s1 * s1 + s2 * s2
    out[1, 1] = s2 * s2 + s3 * s3
    out[2, 2] = s3 * s3 + s1 * s1
    out[0, 1] = out[1, 0] = s2 * s2 * _vertex_cosine(v2, v1, v3)  # d12, d23 meet at star 2
    out[1, 2] = out[2, 1] = s3 * s3 * _vertex_cosine(v3, v2, v1)  # d23, d31 meet at star 3
    out[0, 2] = out[2, 0] = s1 * s1 * _vertex_cosine(v1, v3, v2)  # d31, d12 meet at star 1


@njit(cache=True)
def feature_tolerance(jac, cov, beta: float, floor: float) -> float:
    """Return beta * sqrt(H R H^T) plus the worst case of a `floor` error on every side."""
    var = 0.0
    worst = 0.0
    for i in range(3):
        worst += abs(jac[i])
        for j in range(3):
            var += jac[i] * cov[i, j] * jac[j]
    if not (var < np.inf) or not (worst < np.inf):
        return np.inf
    return beta * math.sqrt(max(var, 0.0)) + floor * worst
