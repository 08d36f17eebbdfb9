# SPDX-License-Identifier: Apache-2.0
"""
One weighted attitude fit over the matched stars of every head, with each head's common errors marginalised.

Each head h contributes body-frame rays b_i (at the common stamp) of ICRS stars r_i, each
with an isotropic 1-sigma s_i [rad]. The body attitude R (body -> ICRS) is perturbed on the
right, R = R0 exp([d]x), so the predicted ray p_i = R^T r_i moves by [p_i]x d and, per head,

    b_i - p_i = [p_i]x (d + S_h z + e_h) + n_i,    n_i ~ N(0, s_i^2) across the ray,

where e_h ~ N(0, Q_h) is an error common to the head's rays, independent of the other heads'
(its alignment-correction uncertainty, the unmodelled acceleration over its stamp offset),
and z ~ N(0, Z) are errors shared by several heads through S_h (3 x K): the body rate error
times each head's stamp offset, or correlated alignment corrections. Per head the stars give
the information I_h = sum_i s_i^-2 (I - p_i p_i^T) and gradient g_h = sum_i s_i^-2 b_i x p_i;
e_h is marginalised in closed form (I_h (I + Q_h I_h)^-1 and (I + I_h Q_h)^-1 g_h, no inverse
of a possibly weak I_h), z by stacking it with d under its prior. Gauss-Newton from the Wahba
solution of all rays (Markley's SVD: the optimum QUEST also finds); the covariance of d is the
d block of the inverse information, in the body frame [rad^2]. Without common errors this is
Wahba's problem over all stars, whose optimum is the start, and the covariance is Shuster & Oh's.
"""
from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np

from ..models.attitude import rotation_vector_to_matrix
from ..models.attitude_estimation import svd_rotation
from .records import HeadResidual


class HeadRays(NamedTuple):
    """
    One head's stars, ready for the joint fit.

    head: name; body_rays: (M, 3) unit rays in the body frame at the common stamp;
    catalog_vectors: (M, 3) ICRS unit vectors; sigmas: (M,) isotropic 1-sigma [rad];
    own_error_covariance: (3, 3) covariance [rad^2] of a rotation common to this head's rays
    only (body frame); shared_error_map: (3, K) how the shared errors z rotate this head's rays.
    """

    head: str
    body_rays: np.ndarray
    catalog_vectors: np.ndarray
    sigmas: np.ndarray
    own_error_covariance: np.ndarray
    shared_error_map: np.ndarray


class JointFit(NamedTuple):
    """rotation: body -> ICRS; covariance: body frame [rad^2]; residuals per head; chi2 over all stars."""

    rotation: np.ndarray
    covariance: np.ndarray
    residuals: dict[str, HeadResidual]
    chi2: float


def fit_heads(heads: Sequence[HeadRays], shared_error_covariance: np.ndarray | None = None,
              iterations: int = 2) -> JointFit:
    """
    Fit one body attitude to every head's stars (see the module docstring).

    heads: at least one, with at least two non-parallel stars in all; shared_error_covariance:
    (K, K) covariance [rad^2 or the units S_h maps to rad] of the shared errors (None: K = 0).
    Raises ValueError when the stars do not determine the attitude.
    """
    if not heads:
        raise ValueError("no head to fit")
    shared_factor = _covariance_factor(shared_error_covariance, heads[0].shared_error_map.shape[1])
    rotation = svd_rotation(np.concatenate([h.body_rays for h in heads]),
                            np.concatenate([h.catalog_vectors for h in heads]),
                            np.concatenate([1.0 / h.sigmas ** 2 for h in heads]))
    for _ in range(iterations):
        step, _ = _joint_step(rotation, heads, shared_factor)
        rotation = rotation @ rotation_vector_to_matrix(step)
    _, covariance = _joint_step(rotation, heads, shared_factor)
    residuals = {h.head: head_residual(rotation, h) for h in heads}
    return JointFit(rotation, covariance, residuals, float(sum(r.chi2 for r in residuals.values())))


def _covariance_factor(covariance: np.ndarray | None, size: int) -> np.ndarray:
    """Return L (K, rank) with L L^T = covariance (positive semi-definite; zero directions left out)."""
    if covariance is None or size == 0:
        return np.zeros((size, 0))
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    keep = values > 1e-12 * max(float(values.max()), 0.0)
    if np.any(values < -1e-9 * max(abs(float(values.max())), 1e-300)):
        raise ValueError("shared error covariance is not positive semi-definite")
    return vectors[:, keep] * np.sqrt(values[keep])


def head_normal_equations(rotation: np.ndarray, head: HeadRays) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return this head's information I_h (3, 3) [rad^-2], gradient g_h (3,) and predicted rays p (M, 3) at rotation."""
    predicted = head.catalog_vectors @ rotation  # rows R^T r
    weights = 1.0 / head.sigmas ** 2
    weighted = weights[:, None] * predicted
    information = weights.sum() * np.eye(3) - weighted.T @ predicted
    profile = head.body_rays.T @ weighted  # sum_i w_i b_i p_i^T: its antisymmetric part is sum_i w_i b_i x p_i
    gradient = np.array([profile[1, 2] - profile[2, 1], profile[2, 0] - profile[0, 2], profile[0, 1] - profile[1, 0]])
    return information, gradient, predicted


def _joint_step(rotation: np.ndarray, heads: Sequence[HeadRays],
                shared_factor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the Gauss-Newton step d (3,) [rad] and the covariance of d (3, 3) [rad^2] at rotation."""
    rank = shared_factor.shape[1]
    information = np.zeros((3 + rank, 3 + rank))
    information[3:, 3:] = np.eye(rank)  # prior of the shared errors, whitened: z = L u, u ~ N(0, I)
    gradient = np.zeros(3 + rank)
    for head in heads:
        head_information, head_gradient, _ = head_normal_equations(rotation, head)
        own = head.own_error_covariance
        marginal_information = head_information @ np.linalg.inv(np.eye(3) + own @ head_information)
        marginal_gradient = np.linalg.solve(np.eye(3) + head_information @ own, head_gradient)
        design = np.hstack([np.eye(3), head.shared_error_map @ shared_factor])
        information += design.T @ (0.5 * (marginal_information + marginal_information.T)) @ design
        gradient += design.T @ marginal_gradient
    try:
        inverse = np.linalg.inv(information)
    except np.linalg.LinAlgError:
        raise ValueError("the stars do not determine the attitude (singular information)") from None
    if not np.all(np.isfinite(inverse)):
        raise ValueError("the stars do not determine the attitude (singular information)")
    return (inverse @ gradient)[:3], 0.5 * (inverse[:3, :3] + inverse[:3, :3].T)


def head_residual(rotation: np.ndarray, head: HeadRays) -> HeadResidual:
    """Return how the head's stars sit on `rotation` (body -> ICRS): see HeadResidual."""
    information, gradient, predicted = head_normal_equations(rotation, head)
    chord2 = np.sum((head.body_rays - predicted) ** 2, axis=1)
    angles = 2.0 * np.arcsin(np.minimum(0.5 * np.sqrt(chord2), 1.0))
    chi2 = float(np.sum(chord2 / head.sigmas ** 2))
    offset_covariance = np.linalg.pinv(information)
    return HeadResidual(int(head.sigmas.size), float(np.sqrt(np.mean(angles ** 2))), chi2,
                        offset_covariance @ gradient, offset_covariance)
