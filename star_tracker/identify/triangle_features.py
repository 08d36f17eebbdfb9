# SPDX-License-Identifier: Apache-2.0
"""
Features of star triangles, measured and cataloged.

Sides, spherical and planar areas and polar moments (`triangle_invariants`, `polar_moment`),
for measured spot triangles with their match tolerances (beta sigma + floor, propagated from
the spots' direction sigmas), and for catalog triangles in bulk (the database build).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from numba import njit

from .geometry import angle_between, triple_product
from .polar_moment import (LANES, lane_scratch, moment_workspace, polar_moment, polar_moment_jacobian,
                           polar_moment_lanes, subdivision_tables)
from .triangle_invariants import (feature_tolerance, heron_area, lhuilier_area, lhuilier_jacobian, planar_jacobians,
                                  side_covariance)


@njit(cache=True)
def _sides_kernel(v1, v2, v3, out):
    for t in range(v1.shape[0]):
        out[t, 0] = angle_between(v1[t], v2[t])
        out[t, 1] = angle_between(v2[t], v3[t])
        out[t, 2] = angle_between(v3[t], v1[t])


def triangle_sides(v1: np.ndarray, v2: np.ndarray, v3: np.ndarray) -> np.ndarray:
    """(T, 3) sides (d12, d23, d31) [rad] of triangles with unit-vector vertices (T, 3) each."""
    v1, v2, v3 = (np.ascontiguousarray(np.atleast_2d(v), dtype=float) for v in (v1, v2, v3))
    out = np.empty((v1.shape[0], 3))
    _sides_kernel(v1, v2, v3, out)
    return out


@njit(cache=True)
def _area_kernel(sides, out, jac):
    for t in range(sides.shape[0]):
        out[t] = lhuilier_area(sides[t, 0], sides[t, 1], sides[t, 2])
        lhuilier_jacobian(sides[t, 0], sides[t, 1], sides[t, 2], jac[t])


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
        out[t] = polar_moment(v1[t], v2[t], v3[t], depth, work)


def spherical_polar_moment(v1: np.ndarray, v2: np.ndarray, v3: np.ndarray, depth: int = 3) -> np.ndarray:
    """Cole's spherical polar moment (eq. 25) [sr rad^2] by subdivision to `depth`."""
    if not (0 <= depth <= 10):
        raise ValueError(f"depth={depth} must be in [0, 10]")
    v1, v2, v3 = (np.ascontiguousarray(np.atleast_2d(v), dtype=float) for v in (v1, v2, v3))
    out = np.empty(v1.shape[0])
    _moment_kernel(v1, v2, v3, depth, out)
    return out


def spherical_polar_moment_fast(v1: np.ndarray, v2: np.ndarray, v3: np.ndarray, depth: int = 3) -> np.ndarray:
    """
    Return the polar moments as the catalog build computes them.

    Many triangles side by side with series for atan and asin (exact triangles beyond their
    range).
    """
    v1, v2, v3 = (np.ascontiguousarray(np.atleast_2d(v), dtype=float) for v in (v1, v2, v3))
    n = v1.shape[0]
    vectors = np.concatenate([v1, v2, v3])
    stars = np.column_stack([np.arange(n), n + np.arange(n), 2 * n + np.arange(n)])
    return catalog_features(vectors, stars, depth).spherical_moment


def planar_area(sides: np.ndarray) -> np.ndarray:
    """Toloei eq. 1: Heron's area [rad^2] of the planar triangle with the given sides."""
    a, b, c = np.atleast_2d(sides).T
    p = (a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c)
    return 0.25 * np.sqrt(np.maximum(p, 0.0))


def planar_polar_moment(sides: np.ndarray) -> np.ndarray:
    """Toloei eq. 2: I = A (a^2 + b^2 + c^2) / 36 [rad^4], the polar moment about the centroid."""
    sides = np.atleast_2d(sides)
    return planar_area(sides) * np.sum(sides**2, axis=1) / 36.0


class FeatureSet(NamedTuple):
    """
    Features of measured triangles with their match tolerances (beta sigma + floor).

    Sides (T, 3) [rad], handedness (T,) sign of det[v1, v2, v3] (0: too flat to tell),
    side_tol (T, 3) [rad], area, area_tol, moment, moment_tol (T,); product, product_tol
    (T,): the side product a b c [rad^3], the third invariant of the shape besides area and
    moment (with them it fixes the triangle up to reflection), used to skip finalists before
    the vertex assignment.
    """

    sides: np.ndarray
    handedness: np.ndarray
    side_tol: np.ndarray
    area: np.ndarray
    area_tol: np.ndarray
    moment: np.ndarray
    moment_tol: np.ndarray
    product: np.ndarray
    product_tol: np.ndarray

    @property
    def triangle_count(self) -> int:
        return int(self.area.size)

    def take(self, index) -> "FeatureSet":
        """Return the features of the triangles `index` (an int or an index array)."""
        index = np.atleast_1d(index)
        return FeatureSet(*(np.ascontiguousarray(column[index]) for column in self))


@njit(cache=True)
def _measured_kernel(rays, sigma, triples, spherical, depth, beta, floor, out):
    """Fill `out` (a FeatureSet of T rows) for the spot triangles `triples` (T, 3)."""
    sides, hand, side_tol = out.sides, out.handedness, out.side_tol
    area, area_tol, moment, moment_tol, product, product_tol = (out.area, out.area_tol, out.moment, out.moment_tol,
                                                                out.product, out.product_tol)
    work = moment_workspace(depth)
    cov = np.empty((3, 3))
    jac_a, jac_m = np.empty(3), np.empty(3)
    for t in range(triples.shape[0]):
        i, j, k = triples[t, 0], triples[t, 1], triples[t, 2]
        v1, v2, v3 = rays[i], rays[j], rays[k]
        a, b, c = angle_between(v1, v2), angle_between(v2, v3), angle_between(v3, v1)
        sides[t, 0], sides[t, 1], sides[t, 2] = a, b, c
        side_covariance(v1, v2, v3, sigma[i], sigma[j], sigma[k], cov)
        # Handedness, or 0 (undecided) for triangles so flat that noise could flip it.
        det = triple_product(v1, v2, v3)
        hand[t] = 0 if abs(det) <= beta * max(sigma[i], sigma[j], sigma[k]) * (a + b + c) else (1 if det > 0.0 else -1)
        pair_sigma = (math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1]), math.sqrt(cov[2, 2]))
        for m in range(3):
            side_tol[t, m] = beta * pair_sigma[m] + floor
        if spherical:
            area[t] = lhuilier_area(a, b, c)
            lhuilier_jacobian(a, b, c, jac_a)
            moment[t] = polar_moment(v1, v2, v3, depth, work)
            polar_moment_jacobian(a, b, c, depth, work, jac_m)
        else:
            area[t] = heron_area(a, b, c)
            moment[t] = area[t] * (a * a + b * b + c * c) / 36.0
            planar_jacobians(a, b, c, jac_a, jac_m)
        area_tol[t] = feature_tolerance(jac_a, cov, beta, floor)
        moment_tol[t] = feature_tolerance(jac_m, cov, beta, floor)
        product[t] = a * b * c
        jac_a[0], jac_a[1], jac_a[2] = b * c, c * a, a * b
        product_tol[t] = feature_tolerance(jac_a, cov, beta, floor)


def measured_features(rays: np.ndarray, sigma: np.ndarray, triples: np.ndarray, spherical: bool,
                      depth: int = 3, beta: float = 3.0, floor: float = 0.0) -> FeatureSet:
    """
    Return the features of spot triangles `triples` (T, 3) of indices into `rays` (N, 3).

    rays in the sensor frame, with per-axis direction 1-sigma `sigma` (N,) [rad]; tolerances are
    beta sigma plus `floor` [rad] of model error on each side, propagated. spherical=True:
    Cole's area and polar moment (depth levels); False: Toloei's planar ones.
    """
    triples = np.ascontiguousarray(triples, dtype=np.int64).reshape(-1, 3)
    t = triples.shape[0]
    out = FeatureSet(np.empty((t, 3)), np.empty(t, np.int8), np.empty((t, 3)), *(np.empty(t) for _ in range(6)))
    _measured_kernel(np.ascontiguousarray(rays, dtype=float), np.ascontiguousarray(sigma, dtype=float), triples,
                     spherical, depth, float(beta), float(floor), out)
    return out


@njit(cache=True, parallel=True)
def _catalog_features_kernel(vectors, stars, depth, tables, out):
    """
    Fill `out` (CatalogFeatures of T rows) for the triangles `stars` (T, 3).

    `tables` are the SubdivisionTables of `depth`.
    """
    sph_area, sph_moment, pl_area, pl_moment, product = (out.spherical_area, out.spherical_moment, out.planar_area,
                                                         out.planar_moment, out.product)
    n = stars.shape[0]
    chunk = 64 * LANES
    for c in numba.prange((n + chunk - 1) // chunk):
        start, stop = c * chunk, min(n, (c + 1) * chunk)
        scratch = lane_scratch(tables)
        polar_moment_lanes(vectors, stars, start, stop, tables, scratch, sph_moment)
        work = moment_workspace(depth)
        for t in range(start, stop):
            v1, v2, v3 = vectors[stars[t, 0]], vectors[stars[t, 1]], vectors[stars[t, 2]]
            a, b, cc = angle_between(v1, v2), angle_between(v2, v3), angle_between(v3, v1)
            sph_area[t] = lhuilier_area(a, b, cc)
            if sph_moment[t] < 0.0:
                sph_moment[t] = polar_moment(v1, v2, v3, depth, work)
            pl_area[t] = heron_area(a, b, cc)
            pl_moment[t] = pl_area[t] * (a * a + b * b + cc * cc) / 36.0
            product[t] = a * b * cc


class CatalogFeatures(NamedTuple):
    """
    Features of catalog triangles (T,) each.

    Spherical area [sr] and polar moment [sr rad^2], planar area [rad^2] and polar moment
    [rad^4], side product a b c [rad^3].
    """

    spherical_area: np.ndarray
    spherical_moment: np.ndarray
    planar_area: np.ndarray
    planar_moment: np.ndarray
    product: np.ndarray


def catalog_features(vectors: np.ndarray, stars: np.ndarray, depth: int) -> CatalogFeatures:
    """
    Return the features of the triangles `stars` (T, 3) of row indices into `vectors` (N, 3) (unit vectors).

    Many side by side (series for atan and asin where exact enough).
    """
    count = stars.shape[0]
    out = CatalogFeatures(*(np.empty(count) for _ in range(5)))
    _catalog_features_kernel(np.ascontiguousarray(vectors, dtype=float), stars, depth, subdivision_tables(depth), out)
    return out
