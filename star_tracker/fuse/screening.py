# SPDX-License-Identifier: Apache-2.0
"""
Checking one head's observation before fusion: what is rejected whole, what star is left out.

Rejected whole (with the reason): a head not configured, a malformed record (a mounting or
head attitude that is not a rotation, array shapes that disagree, a head covariance that is
not symmetric positive definite), or fewer usable stars than the minimum. Left out star by
star (and counted): a ray or catalog vector that is not finite or not of unit length (within
UNIT_TOLERANCE), a sigma that is not finite and > 0.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Iterable, NamedTuple

import numpy as np

from ..models.matrix_checks import covariance_problem, rotation_problem
from .records import HeadObservation

UNIT_TOLERANCE = 1e-3  # largest | |v| - 1 | of a usable unit vector (float32 messages are good to 1e-7)

UNKNOWN_HEAD = "unknown_head"
INVALID = "invalid"
TOO_FEW_STARS = "too_few_stars"


class Screening(NamedTuple):
    """
    The verdict on one observation.

    observation: the usable part (bad stars removed, vectors renormalised), None when rejected;
    rejection: "" when accepted, else UNKNOWN_HEAD, INVALID or TOO_FEW_STARS; detail: why,
    in words; excluded_stars: stars left out.
    """

    observation: HeadObservation | None
    rejection: str
    detail: str
    excluded_stars: int


def screen_observation(observation: HeadObservation, known_heads: Iterable[str], min_stars: int) -> Screening:
    """Return the usable part of `observation` or why it is rejected (see the module docstring)."""
    if observation.head not in set(known_heads):
        return Screening(None, UNKNOWN_HEAD, f"head {observation.head!r} is not configured", 0)
    problem = _record_problem(observation)
    if problem:
        return Screening(None, INVALID, f"head {observation.head!r}: {problem}", 0)
    rays = np.asarray(observation.rays, dtype=float)
    catalog = np.asarray(observation.catalog_vectors, dtype=float)
    sigmas = np.asarray(observation.ray_sigmas, dtype=float)
    with np.errstate(invalid="ignore", over="ignore"):
        ray_norm, catalog_norm = np.linalg.norm(rays, axis=1), np.linalg.norm(catalog, axis=1)
        usable = (np.all(np.isfinite(rays), axis=1) & np.all(np.isfinite(catalog), axis=1)
                  & (np.abs(ray_norm - 1.0) <= UNIT_TOLERANCE) & (np.abs(catalog_norm - 1.0) <= UNIT_TOLERANCE)
                  & np.isfinite(sigmas) & (sigmas > 0.0))
    excluded = int(usable.size - np.count_nonzero(usable))
    if np.count_nonzero(usable) < min_stars:
        return Screening(None, TOO_FEW_STARS, f"head {observation.head!r}: {np.count_nonzero(usable)} usable stars "
                         f"({excluded} left out), at least {min_stars} needed", excluded)
    clean = replace(observation, rays=rays[usable] / ray_norm[usable, None],
                    catalog_vectors=catalog[usable] / catalog_norm[usable, None], ray_sigmas=sigmas[usable],
                    mounting=np.asarray(observation.mounting, dtype=float))
    return Screening(clean, "", "", excluded)


def _record_problem(observation: HeadObservation) -> str:
    """Return what is malformed in the record as a whole ("" if nothing)."""
    if not isinstance(observation.stamp_ns, (int, np.integer)):
        return f"stamp_ns must be an integer [ns], got {type(observation.stamp_ns).__name__}"
    problem = rotation_problem(observation.mounting)
    if problem:
        return f"mounting is not a rotation: {problem}"
    rays, catalog, sigmas = (np.shape(observation.rays), np.shape(observation.catalog_vectors),
                             np.shape(observation.ray_sigmas))
    if len(rays) != 2 or rays[1:] != (3,) or catalog != rays or sigmas != rays[:1]:
        return f"rays {rays}, catalog_vectors {catalog} and ray_sigmas {sigmas} must be (M, 3), (M, 3), (M,)"
    if (observation.head_rotation is None) != (observation.head_covariance is None):
        return "head_rotation and head_covariance come together or not at all"
    if observation.head_rotation is not None:
        problem = rotation_problem(observation.head_rotation)
        if problem:
            return f"head_rotation is not a rotation: {problem}"
        problem = covariance_problem(observation.head_covariance)
        if problem:
            return f"head_covariance [rad^2] is {problem}"
    return ""
