# SPDX-License-Identifier: Apache-2.0
"""
A simulated spacecraft with several star tracker heads, for the fusion tests: observations with truth.

Each head sees the Hipparcos stars (Hp <= MAGNITUDE_LIMIT) that the nominal 15 deg, 1024 x
1024 camera images at its true attitude R_body exp(...) M_true^T; each ray carries isotropic
Gaussian noise across it, with a 1-sigma that grows with the star's magnitude
(ray_sigma_rad). The observation states the nominal mounting, so an injected misalignment is
what the fusion must live with or the alignment filter must find.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from star_tracker.fuse import HeadObservation
from star_tracker.models.attitude import ARCSEC, rotation_vector_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.models.catalog import StarCatalog

CAMERA = CameraModel.from_fov(1024, 1024, np.radians(15.0))
MAGNITUDE_LIMIT = 7.0
SIGMA_AT_MAG5_PX = 0.1  # centroid 1-sigma per axis of an Hp = 5 star [px]; x 10^(0.2 dm) with magnitude


def head_mounting(boresight_body: np.ndarray, right_body: np.ndarray) -> np.ndarray:
    """Return the body -> head rotation of a head whose +Z and +X point along the given body-frame axes."""
    z = np.asarray(boresight_body, dtype=float) / np.linalg.norm(boresight_body)
    x = np.asarray(right_body, dtype=float) - np.dot(right_body, z) * z
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])  # rows: head axes in the body frame


# Two heads 90 deg apart: A along body +Z, B along body +X.
MOUNT_A = head_mounting([0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
MOUNT_B = head_mounting([1.0, 0.0, 0.0], [0.0, 1.0, 0.0])


def ray_sigma_rad(magnitude: np.ndarray) -> np.ndarray:
    """Return each star's ray 1-sigma [rad]: SIGMA_AT_MAG5_PX at Hp 5, x 10^(0.2 (Hp - 5)), the camera's pixel scale."""
    return SIGMA_AT_MAG5_PX * 10.0 ** (0.2 * (np.asarray(magnitude) - 5.0)) * CAMERA.pixel_scale_rad


@dataclass(frozen=True)
class Sky:
    """The stars a head can see: ICRS unit vectors (N, 3) and Hp magnitudes (N,)."""

    vectors: np.ndarray
    magnitudes: np.ndarray

    @staticmethod
    def from_catalog(catalog: StarCatalog) -> "Sky":
        stars = catalog.brighter_than(MAGNITUDE_LIMIT)
        return Sky(stars.unit_vectors(), stars.hp.astype(float))


def observe(sky: Sky, head: str, mounting: np.ndarray, body_rotation: np.ndarray, stamp_ns: int,
            rng: np.random.Generator, misalignment: np.ndarray | None = None) -> HeadObservation:
    """
    Return what a head measures at stamp_ns with the body at body_rotation (body -> ICRS, at that stamp).

    mounting: nominal body -> head (stated in the observation); misalignment: body-frame
    rotation vector [rad] by which the head is really turned from it (mounting.py's correction).
    """
    true_mounting = mounting @ rotation_vector_to_matrix(-(np.zeros(3) if misalignment is None else misalignment))
    head_rotation = body_rotation @ true_mounting.T
    rays = sky.vectors @ head_rotation  # rows R^T r: head frame
    u, v, front = CAMERA.project(rays)
    seen = front & CAMERA.in_image(u, v, margin=3.0)
    rays, catalog, sigmas = rays[seen], sky.vectors[seen], ray_sigma_rad(sky.magnitudes[seen])
    return HeadObservation(head, int(stamp_ns), mounting, catalog, noisy_rays(rays, sigmas, rng), sigmas)


def noisy_rays(rays: np.ndarray, sigmas: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Return unit rays moved by Gaussian noise of 1-sigma `sigmas` [rad] along each of two axes across the ray."""
    helper = np.where(np.abs(rays[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(rays, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(rays, e1)
    noise = sigmas[:, None] * (rng.normal(size=(len(rays), 1)) * e1 + rng.normal(size=(len(rays), 1)) * e2)
    moved = rays + noise
    return moved / np.linalg.norm(moved, axis=1, keepdims=True)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Return a uniformly distributed rotation matrix."""
    q = rng.normal(size=4)
    axis = q[:3] / np.linalg.norm(q[:3])
    return rotation_vector_to_matrix(axis * 2.0 * np.arctan2(np.linalg.norm(q[:3]), q[3]))


def error_vector(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Return the small-angle error dtheta [rad] of estimate = truth exp([dtheta]x), in the estimate's own frame."""
    from star_tracker.models.attitude import matrix_to_rotation_vector

    return matrix_to_rotation_vector(truth.T @ estimate)


def arcsec(radians: np.ndarray | float) -> np.ndarray | float:
    """Return radians in arcseconds."""
    return np.asarray(radians) / ARCSEC
