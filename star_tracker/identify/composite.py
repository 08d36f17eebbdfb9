# SPDX-License-Identifier: Apache-2.0
"""
Toloei, Arani & Abaszadeh's composite of the pyramid and planar triangle methods (seed 001, sec. 3.5).

A base triangle of three spots is described by its planar area (Heron with s = (a+b+c)/2,
eq. 1) and polar moment I = A (a^2+b^2+c^2)/36 (eq. 2), a, b, c its sides [rad]. Catalog
triangles within beta sigma of the area (k-vector over planar area) and of the moment are the
base candidates; as in `spherical_triangle`, a candidate's vertices are assigned to the spots
by the sides, and the handedness must agree (mirror test). Then, like the pyramid, a fourth
spot r is sought: the three further triangles (i, j, r), (i, k, r), (j, k, r) must each match
the catalog triangles (s_i, s_j, s), (s_i, s_k, s), (s_j, s_k, s) on planar area and
moment for one catalog star s ("a unique response"). The catalog stars s tried are the
database neighbours of s_i, so the fourth star need not be among the thinned guide stars.
Confirmed four-star identities are the hypotheses, the base candidates with the most
confirming fourth spots first.

Base triangles are enumerated in Mortari's pyramid order over the brightest pattern spots;
for fields crowded with false stars, the enumeration then continues over fainter spots (one
new spot at a time, each with every pair of the brighter ones) up to `max_spots`, within the
time budget.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, NamedTuple

import numpy as np
from numba import njit

from .base import IdentifyConfig, StarIdentifier
from .spot_geometry import SpotGeometry
from .database import StarDatabase
from .geometry import angle_between, chord_angle, pyramid_triangles, triple_product
from .spherical_triangle import fitting_triples
from .triangle_database import TriangleConfig, load_or_build_triangles
from .triangle_features import measured_features
from .triangle_invariants import feature_tolerance, heron_area, planar_jacobians, side_covariance
from .triangle_matching import match_triangles, warm_up
from .deadline import Deadline


@dataclass(frozen=True)
class CompositeSettings:
    """
    Configure the composite method.

    max_spots: spots (brightest first) the base triangles and fourth stars are drawn from
    once the brightest `pattern_count` are exhausted; batch_size: base triangles matched per
    catalog search (small: the first good triangle is reached sooner).
    """

    max_spots: int = 150
    batch_size: int = 32

    def __post_init__(self) -> None:
        if not (4 <= self.max_spots <= 1000):
            raise ValueError(f"max_spots={self.max_spots} must be in [4, 1000]")
        if not (1 <= self.batch_size <= 100_000):
            raise ValueError(f"batch_size={self.batch_size} must be in [1, 1e5]")


class Neighbours(NamedTuple):
    """Symmetric CSR of the database pairs: the neighbours of star s are indices[indptr[s]:indptr[s + 1]]."""

    indptr: np.ndarray
    indices: np.ndarray


class SpotDistances(NamedTuple):
    """
    The spots of one frame.

    Rays (N, 3) sensor frame, sigma (N,) [rad], dist (N, N) inter-spot angles [rad];
    dist_order (N, N) each row's spots by distance, dist_sorted (N, N) the distances in that
    order.
    """

    rays: np.ndarray
    sigma: np.ndarray
    dist: np.ndarray
    dist_order: np.ndarray
    dist_sorted: np.ndarray


class MatchTolerance(NamedTuple):
    """beta: sigma multiplier; floor: model error per side [rad]; loose: the fourth star's distance prefilter [rad]."""

    beta: float
    floor: float
    loose: float


class FourthStars(NamedTuple):
    """
    Per base candidate (C,).

    Count of fourth spots with a unique response; the brightest such spot and its star (-1
    if none).
    """

    count: np.ndarray
    spot: np.ndarray
    star: np.ndarray


def neighbour_lists(database: StarDatabase) -> Neighbours:
    """Symmetric CSR of every database pair (all angles stored)."""
    a = np.concatenate([database.pair_a, database.pair_b]).astype(np.int64)
    b = np.concatenate([database.pair_b, database.pair_a]).astype(np.int32)
    order = np.argsort(a, kind="stable")
    indptr = np.zeros(database.star_count + 1, np.int64)
    np.cumsum(np.bincount(a, minlength=database.star_count), out=indptr[1:])
    return Neighbours(indptr, b[order])


_NEIGHBOURS: dict[str, Neighbours] = {}


@njit(cache=True)
def _planar_match(frame, spots, vectors, stars, tol, scratch) -> bool:
    """
    Tell whether a spot triangle and a catalog triangle agree on planar area and polar moment.

    Spot triangle `spots` (x, y, r) of SpotDistances `frame`, catalog triangle `stars` (sx, sy,
    s): within MatchTolerance `tol` (eqs. 1-2), with the same handedness. scratch: (cov (3, 3),
    jac_a (3,), jac_m (3,)).
    """
    rays, sigma, dist = frame.rays, frame.sigma, frame.dist
    x, y, r = spots
    sx, sy, s = stars
    beta, floor = tol.beta, tol.floor
    cov, jac_a, jac_m = scratch
    a, b, c = dist[x, y], dist[y, r], dist[r, x]
    ca = angle_between(vectors[sx], vectors[sy])
    cb = angle_between(vectors[sy], vectors[s])
    cc = angle_between(vectors[s], vectors[sx])
    side_covariance(rays[x], rays[y], rays[r], sigma[x], sigma[y], sigma[r], cov)
    planar_jacobians(a, b, c, jac_a, jac_m)
    area = heron_area(a, b, c)
    cat_area = heron_area(ca, cb, cc)
    if abs(area - cat_area) > feature_tolerance(jac_a, cov, beta, floor):
        return False
    moment = area * (a * a + b * b + c * c) / 36.0
    cat_moment = cat_area * (ca * ca + cb * cb + cc * cc) / 36.0
    if abs(moment - cat_moment) > feature_tolerance(jac_m, cov, beta, floor):
        return False
    det = triple_product(rays[x], rays[y], rays[r])
    if abs(det) <= beta * max(sigma[x], sigma[y], sigma[r]) * (a + b + c):
        return True  # too flat for a handedness test
    return (det > 0.0) == (triple_product(vectors[sx], vectors[sy], vectors[s]) > 0.0)


@njit(cache=True)
def _confirm_kernel(base_spots, base_stars, frame, neighbours, vectors, tol, out):
    """
    For each base candidate (stars (C, 3) of the spots base_spots = (i, j, k)).

    The fourth spots r for which exactly one neighbour star s of s_i makes all three side
    triangles match. Writes FourthStars `out`: how many such r; the brightest one and its
    star.
    """
    i, j, k = base_spots
    dist, dist_order, dist_sorted = frame.dist, frame.dist_order, frame.dist_sorted
    nb_ptr, nb_idx = neighbours.indptr, neighbours.indices
    loose = tol.loose
    out_count, out_r, out_s = out.count, out.spot, out.star
    n = dist.shape[0]
    hits = np.zeros(n, np.int64)
    star_of = np.full(n, -1, np.int64)
    scratch = (np.empty((3, 3)), np.empty(3), np.empty(3))
    row_i = dist_sorted[i]
    for c in range(base_stars.shape[0]):
        si, sj, sk = base_stars[c, 0], base_stars[c, 1], base_stars[c, 2]
        hits[:] = 0
        for p in range(nb_ptr[si], nb_ptr[si + 1]):
            s = nb_idx[p]
            if s == sj or s == sk:
                continue
            d_si = angle_between(vectors[s], vectors[si])
            lo = np.searchsorted(row_i, d_si - loose)
            hi = np.searchsorted(row_i, d_si + loose, side="right")
            if lo >= hi:
                continue
            d_sj = angle_between(vectors[s], vectors[sj])
            d_sk = angle_between(vectors[s], vectors[sk])
            for m in range(lo, hi):
                r = dist_order[i, m]
                if r == i or r == j or r == k:
                    continue
                if abs(dist[j, r] - d_sj) > loose or abs(dist[k, r] - d_sk) > loose:
                    continue
                if not _planar_match(frame, (i, j, r), vectors, (si, sj, s), tol, scratch):
                    continue
                if not _planar_match(frame, (i, k, r), vectors, (si, sk, s), tol, scratch):
                    continue
                if not _planar_match(frame, (j, k, r), vectors, (sj, sk, s), tol, scratch):
                    continue
                hits[r] += 1
                star_of[r] = s
        out_count[c] = 0
        out_r[c] = -1
        out_s[c] = -1
        for r in range(n):
            if hits[r] == 1:  # a unique response
                if out_count[c] == 0:
                    out_r[c], out_s[c] = r, star_of[r]
                out_count[c] += 1


def base_triangle_batches(pattern_count: int, spot_count: int, size: int) -> Iterator[np.ndarray]:
    """
    Return base triangles in batches of at most `size`.

    Mortari's pyramid order over the pattern spots, then for each further spot k every
    triple (i, j, k) with i < j < k.
    """
    first = pyramid_triangles(pattern_count)
    for start in range(0, first.shape[0], size):
        yield first[start:start + size]
    for k in range(pattern_count, spot_count):
        i, j = np.triu_indices(k, 1)
        triples = np.column_stack([i, j, np.full(i.size, k)]).astype(np.int64)
        for start in range(0, triples.shape[0], size):
            yield triples[start:start + size]


class CompositeIdentifier(StarIdentifier):
    """Toloei's composite pyramid / planar triangle identification."""

    name = "composite"

    def __init__(self, database: StarDatabase, config: IdentifyConfig,
                 triangle_config: TriangleConfig | None = None, settings: CompositeSettings | None = None):
        super().__init__(database, config)
        self.triangles = load_or_build_triangles(database, triangle_config)
        self.settings = settings or CompositeSettings()
        key = database.config.cache_key()
        if key not in _NEIGHBOURS:
            _NEIGHBOURS[key] = neighbour_lists(database)
        self.neighbours = _NEIGHBOURS[key]
        warm_up(self.triangles, database)
        self._warm_up_confirmation()

    def _warm_up_confirmation(self) -> None:
        """Compile (or load) the fourth-star kernel now rather than in the first frame."""
        rays = np.array([[0.0, 0.0, 1.0], [0.01, 0.0, 1.0], [0.0, 0.01, 1.0], [0.01, 0.01, 1.0]])
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        dist = np.zeros((4, 4))
        frame = SpotDistances(rays, np.full(4, 1e-5), dist, np.zeros((4, 4), np.int64), dist)
        out = FourthStars(*(np.zeros(1, np.int64) for _ in range(3)))
        _confirm_kernel((0, 1, 2), np.zeros((1, 3), np.int64), frame, self.neighbours, self.database.vectors,
                        MatchTolerance(3.0, 0.0, 1e-4), out)

    def hypotheses(self, geometry: SpotGeometry, deadline: Deadline) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        n = min(geometry.rays.shape[0], self.settings.max_spots)
        if n < 4:
            return
        rays = np.ascontiguousarray(geometry.rays[:n])
        sigma = np.ascontiguousarray(geometry.sigma[:n])
        beta, floor = self.config.sigma_multiplier, self.config.angle_tolerance_floor_rad
        dist = chord_angle(rays[:, None], rays[None])
        dist_order = np.argsort(dist, axis=1, kind="stable")
        dist_sorted = np.ascontiguousarray(np.take_along_axis(dist, dist_order, axis=1))
        # Prefilter on the fourth star's three distances: twice the widest side tolerance.
        loose = 2.0 * float(self.angle_tolerance(np.max(sigma), np.max(sigma)))
        slack = 0.5 * loose
        frame = SpotDistances(rays, sigma, dist, dist_order, dist_sorted)
        tol = MatchTolerance(float(beta), float(floor), loose)
        vectors = self.database.vectors
        self.stats.update(base_triangles=0, base_candidates=0, confirmed=0, spots_used=0)
        yielded: set[tuple] = set()
        for batch in base_triangle_batches(min(geometry.pattern_count, n), n, self.settings.batch_size):
            if deadline.passed():
                return
            self.stats["spots_used"] = int(batch.max()) + 1 if batch.size else 0
            triples = fitting_triples(rays, batch, self.triangles.config.max_side_rad, slack)
            if triples.shape[0] == 0:
                continue
            self.stats["base_triangles"] += int(triples.shape[0])
            features = measured_features(rays, sigma, triples, spherical=False, beta=beta, floor=floor)
            matches = match_triangles(self.triangles, self.database, features, spherical=False,
                                      cap=self.config.max_candidates_per_pattern)
            bounds = np.searchsorted(matches.query, np.arange(triples.shape[0] + 1))
            for t in np.flatnonzero(np.diff(bounds)):
                if deadline.passed():
                    return
                i, j, k = (int(v) for v in triples[t])
                base = np.ascontiguousarray(matches.stars[bounds[t]:bounds[t + 1]])
                self.stats["base_candidates"] += int(base.shape[0])
                fourth = FourthStars(*(np.empty(base.shape[0], np.int64) for _ in range(3)))
                _confirm_kernel((i, j, k), base, frame, self.neighbours, vectors, tol, fourth)
                count, fourth_spot, fourth_star = fourth
                for c in np.argsort(-count, kind="stable"):
                    if count[c] == 0:
                        break
                    spots = np.array([i, j, k, fourth_spot[c]])
                    stars = np.append(base[c], fourth_star[c]).astype(np.int64)
                    key = tuple(sorted(zip(spots.tolist(), stars.tolist())))
                    if key in yielded:
                        continue
                    yielded.add(key)
                    self.stats["confirmed"] += 1
                    yield spots, stars
