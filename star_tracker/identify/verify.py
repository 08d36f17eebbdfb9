"""Verification of a candidate attitude against every spot, with a false-positive bound.

Null hypothesis: the candidate attitude is wrong, so the guide stars it projects into the
image are unrelated to the spots. Then each spot not used to form the hypothesis falls
within the match radius r of one of the K projected stars with probability at most
    p = K * pi * r^2 / (W * H)
(union bound over the stars' disks), independently of the others. The chance that m or more
of the n remaining spots match by luck is the binomial tail P(X >= m; n, p). Testing H
hypotheses in one frame multiplies this bound by H (Bonferroni). A candidate is accepted
only if H * P(X >= m; n, p) <= the configured bound (default 1e-6).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import bdtrc

from ..camera import CameraModel
from .database import StarDatabase


@dataclass(frozen=True)
class Verification:
    """spot_index, star_index: one-to-one matches (database star indices);
    distance_px: projected-star to spot distance [px]; false_positive_probability: the
    per-hypothesis binomial tail (multiply by hypotheses for the frame's bound);
    stars_in_view: K; radius_px: r."""

    spot_index: np.ndarray
    star_index: np.ndarray
    distance_px: np.ndarray
    false_positive_probability: float
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
    """Greedy one-to-one nearest matches within radius: (spot idx, star idx, distance)."""
    if spot_x.size == 0 or star_u.size == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty, np.zeros(0)
    d = np.hypot(spot_x[:, None] - star_u[None, :], spot_y[:, None] - star_v[None, :])
    spot_i, star_j = np.nonzero(d <= radius_px)
    dist = d[spot_i, star_j]
    order = np.argsort(dist, kind="stable")
    used_spot = np.zeros(spot_x.size, bool)
    used_star = np.zeros(star_u.size, bool)
    keep = []
    for k in order:
        si, sj = spot_i[k], star_j[k]
        if not used_spot[si] and not used_star[sj]:
            used_spot[si] = used_star[sj] = True
            keep.append(k)
    keep = np.asarray(keep, dtype=np.int64)
    return spot_i[keep], star_j[keep], dist[keep]


def binomial_tail(successes: int, trials: int, p: float) -> float:
    """P(X >= successes) for X ~ Binomial(trials, p)."""
    if successes <= 0:
        return 1.0
    if successes > trials:
        return 0.0
    return float(bdtrc(successes - 1, trials, min(max(p, 0.0), 1.0)))


def verify(rotation: np.ndarray, spot_x: np.ndarray, spot_y: np.ndarray, database: StarDatabase,
           camera: CameraModel, radius_px: float, hypothesis_spots: int) -> Verification:
    """Match the spots to the database stars projected with `rotation` and bound the
    probability that so many matches arise by chance. `hypothesis_spots` spots were used to
    form the candidate and count neither as trials nor as evidence."""
    star_idx, u, v = project_database(rotation, database, camera)
    spot_i, star_j, dist = match_spots(spot_x, spot_y, u, v, radius_px)
    trials = max(spot_x.size - hypothesis_spots, 0)
    evidence = max(spot_i.size - hypothesis_spots, 0)
    p = min(1.0, star_idx.size * np.pi * radius_px**2 / (camera.width * camera.height))
    return Verification(spot_i, star_idx[star_j], dist, binomial_tail(evidence, trials, p),
                        int(star_idx.size), float(radius_px))
