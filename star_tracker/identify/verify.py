# SPDX-License-Identifier: Apache-2.0
"""
Verification of a candidate attitude against every spot, with a false-positive bound.

Null hypothesis: the spots are unrelated to the catalog stars they are matched to (false
stars, or real stars given a wrong identity). For a set of m spots, unit vectors b_i with
1-sigma direction errors s_i, the catalog stars are modelled as a uniform random field of
density rho [1/sr]. The expected number of ordered catalog m-tuples that some rotation R
maps onto the spots with weighted residual chi^2 = sum |b_i - R^T r_i|^2 / s_i^2 <= c is the
density of tuples times the volume of a tube of radius sqrt(c) around the 3-D orbit of
rotations, in coordinates scaled by s_i:

    lambda_m(c) = prod_i (rho s_i^2) * 8 pi^2 sqrt(det G) * V_{2m-3}(sqrt(c)),
    G = sum_i (I - b_i b_i^T) / s_i^2   (the inverse of the QUEST covariance),

with 8 pi^2 the volume of SO(3) and V_d(r) the volume of a d-ball. Magnitudes add
independent evidence when fluxes are known: with the zero point fitted on the matches and
d the largest magnitude residual (at least `magnitude_floor`), the chance that random
catalog stars agree as well is M = prod_i [F(m_i + d) - F(m_i - d)] over all but one star
(one degree of freedom went into the zero point), F the catalog magnitude CDF.

For one spot subset the statistic T = lambda_m(c) * M satisfies P(T <= t) <= t (1 + ln 1/t)
(a product of two p-values). The search could have found any of the C(n, m) subsets of the
n spots, for any m in 4..n, so the bound on a chance solution is

    P_fp <= (n - 3) * C(n, m) * T (1 + ln 1/T),

and a candidate is accepted only when P_fp <= the configured bound (default 1e-6). This
covers every hypothesis any algorithm tests in the frame. rho is the larger of the whole
catalog's mean density and the density of catalog stars in this field of view.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models.camera import CameraModel
from . import kernels
from .database import StarDatabase


@dataclass(frozen=True)
class Verification:
    """
    spot_index, star_index.

    One-to-one matches (database star indices); distance_px: projected-star to spot distance
    [px]; stars_in_view: database stars projected inside the image; radius_px: match radius
    [px].
    """

    spot_index: np.ndarray
    star_index: np.ndarray
    distance_px: np.ndarray
    stars_in_view: int
    radius_px: float


def project_database(rotation: np.ndarray, database: StarDatabase, camera: CameraModel):
    """Database stars inside the image for a sensor->ICRS rotation: (indices, u, v) [px]."""
    boresight = rotation[:, 2]
    cos_limit = np.cos(min(camera.half_diagonal_fov_rad + 1e-3, np.pi / 2))
    near = np.flatnonzero(database.vectors @ boresight > cos_limit)
    u, v, front = camera.project(database.vectors[near] @ rotation)
    inside = front & camera.in_image(u, v)
    return near[inside], u[inside], v[inside]


def match_spots(spot_x: np.ndarray, spot_y: np.ndarray, star_u: np.ndarray, star_v: np.ndarray,
                radius_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Each spot's nearest star within the radius: (spot idx, star idx, distance).

    A star with a second spot within twice the radius is ambiguous (e.g. a false object
    beside a star that pulled the fit toward itself) and matches no spot, so no identity is
    claimed for the wrong one.
    """
    if spot_x.size == 0 or star_u.size == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty, np.zeros(0)
    dx = spot_x[:, None] - star_u[None, :]
    dy = spot_y[:, None] - star_v[None, :]
    squared = dx * dx + dy * dy  # hypot over every pair cost 2-3x more
    nearest = np.argmin(squared, axis=1)
    rows = np.arange(spot_x.size)
    dist = np.hypot(dx[rows, nearest], dy[rows, nearest])
    spot_i = np.flatnonzero(dist <= radius_px)
    star_j = nearest[spot_i]
    unique = np.count_nonzero(squared[:, star_j] <= (2.0 * radius_px) ** 2, axis=0) == 1
    spot_i, star_j = spot_i[unique], star_j[unique]
    return spot_i, star_j, dist[spot_i]


MIN_STARS = 4


def log_chance_tuples(body: np.ndarray, sigma: np.ndarray, chi2: float, density_per_sr: float) -> float:
    """
    Return ln lambda_m(c): expected number of catalog m-tuples fitting the m unit vectors `body`.

    Uniform density [1/sr]; `body` in the sensor frame (sigma [rad] each), fitting with weighted
    chi^2 <= `chi2`.
    """
    # Contiguous float64 always: one compiled specialisation, the one the warm-ups compile.
    return float(kernels.log_chance_tuples(np.ascontiguousarray(body, float), np.ascontiguousarray(sigma, float),
                                           float(chi2), float(density_per_sr)))


def log_magnitude_agreement(spot_magnitude: np.ndarray, star_magnitude: np.ndarray,
                            sorted_catalog_magnitudes: np.ndarray, floor: float) -> float:
    """
    Return ln M: chance that random catalog stars agree with the spots' instrumental magnitudes.

    As well as the matched stars do (zero point fitted); 0 when magnitudes are unknown.
    """
    return float(kernels.log_magnitude_agreement(np.asarray(spot_magnitude, float), np.asarray(star_magnitude, float),
                                                 np.asarray(sorted_catalog_magnitudes, float), float(floor)))


def false_positive_bound(log_statistic: float, spots: int, matched: int) -> float:
    """P_fp <= (n - 3) C(n, m) T (1 + ln 1/T) for T = exp(log_statistic) (see module doc)."""
    return float(kernels.false_positive_bound(float(log_statistic), int(spots), int(matched), MIN_STARS))


def verify(rotation: np.ndarray, spot_x: np.ndarray, spot_y: np.ndarray, database: StarDatabase,
           camera: CameraModel, radius_px: float) -> Verification:
    """
    Match the spots to the database stars projected with `rotation` (sensor -> ICRS).

    One-to-one nearest matches within `radius_px`.
    """
    star_idx, u, v = project_database(rotation, database, camera)
    spot_i, star_j, dist = match_spots(spot_x, spot_y, u, v, radius_px)
    return Verification(spot_i, star_idx[star_j], dist, int(star_idx.size), float(radius_px))
