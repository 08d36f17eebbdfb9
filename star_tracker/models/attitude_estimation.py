# SPDX-License-Identifier: Apache-2.0
"""
Attitude estimation from matched direction pairs (sensor-frame measurements, ICRS catalog).

Wahba's problem by QUEST (with Shuster & Oh's covariance), the Davenport q-method and the SVD
method as cross-checks, and maximum-likelihood refinement with per-direction anisotropic
covariances. Conventions (quaternion order, frames) as in attitude.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .attitude import matrix_to_quaternion, skew


# A direction whose residual covariance keeps less than this share of its own (its leverage
# above 1 - LEVERAGE_FLOOR in both axes together) has no residual to judge by.
LEVERAGE_FLOOR = 1e-4


@dataclass(frozen=True)
class AttitudeSolution:
    """
    quaternion: (x, y, z, w) sensor -> ICRS.

    Rotation: same as a 3x3 matrix; covariance: 3x3 small-angle attitude error covariance in
    the sensor frame [rad^2]; loss: Wahba loss at the optimum (sum of weighted squared
    residuals / 2).
    """

    quaternion: np.ndarray
    rotation: np.ndarray
    covariance: np.ndarray
    loss: float


def _profile_z(b_matrix: np.ndarray) -> np.ndarray:
    """Return the vector z of Davenport's K from the attitude profile matrix B (its antisymmetric part)."""
    return np.array([b_matrix[1, 2] - b_matrix[2, 1], b_matrix[2, 0] - b_matrix[0, 2],
                     b_matrix[0, 1] - b_matrix[1, 0]])


def _davenport_k(body: np.ndarray, ref: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # Attitude profile matrix B = sum_i w_i b_i r_i^T (Shuster's convention: A maps ref -> body).
    b_matrix = (weights[:, None] * body).T @ ref
    s = b_matrix + b_matrix.T
    z = _profile_z(b_matrix)
    k = np.zeros((4, 4))
    k[:3, :3] = s - np.trace(b_matrix) * np.eye(3)
    k[:3, 3] = z
    k[3, :3] = z
    k[3, 3] = np.trace(b_matrix)
    return k, b_matrix


def attitude_covariance(body: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """
    QUEST measurement-model covariance in the sensor frame [rad^2].

    P = [sum_i sigma_i^-2 (I - b_i b_i^T)]^-1 (Shuster & Oh).
    """
    body = np.asarray(body, dtype=float).reshape(-1, 3)
    weights = 1.0 / np.asarray(sigmas, dtype=float) ** 2
    info = np.sum(weights) * np.eye(3) - (weights[:, None] * body).T @ body
    # Singular (parallel vectors): a tiny ridge keeps the unobservable axis finite but huge,
    # never the zero variance (false certainty) a pseudo-inverse would report there.
    if abs(np.linalg.det(info)) < 1e-12 * np.trace(info) ** 3:
        return np.linalg.inv(info + 1e-12 * np.trace(info) * np.eye(3))
    return np.linalg.inv(info)


def refine_with_covariances(rotation: np.ndarray, body: np.ndarray, ref: np.ndarray, ray_cov: np.ndarray | None = None,
                            *, jacobian: np.ndarray | None = None, pixel_cov: np.ndarray | None = None,
                            used: np.ndarray | None = None,
                            iterations: int = 2) -> tuple[AttitudeSolution, np.ndarray, np.ndarray]:
    """
    Refine an attitude by maximum likelihood when each measured direction has its own error covariance.

    A 2-D covariance: an anisotropic centroid, e.g. a streak, is far larger along the smear.

    rotation: sensor -> ICRS start (e.g. QUEST, or any fit within a few arcmin); body (N, 3)
    measured sensor-frame unit vectors; ref (N, 3) their ICRS catalog vectors; the error of
    each body vector as ray_cov (N, 3, 3) [rad^2], or as a pixel covariance pixel_cov
    (N, 2, 2) [px^2] with the ray's derivative jacobian (N, 3, 2) [rad/px] (ray covariance
    J C J^T); used (N,) bool: the directions fitted (default all; the others only get chi^2).
    Gauss-Newton on chi^2 = sum_i r_i^T W_i r_i, r_i = E_i^T (b_i - R^T r_i) the residual in
    b_i's tangent plane (orthonormal basis E_i), W_i = (E_i^T ray_cov_i E_i)^-1, perturbation
    R exp([d]x) (the predicted p = R^T r moves by [p]x d). With isotropic covariances this is
    Wahba's problem, whose optimum QUEST finds, and the covariance is Shuster & Oh's.
    Returns the solution (covariance P = (sum G_i^T W_i G_i)^-1 over the used directions
    [rad^2], sensor frame, G_i = E_i^T [p_i]x; loss: their chi^2 / 2), every direction's
    studentized chi^2 (2 DOF) and its residual angle arccos(b_i . R^T r_i) [rad] at it.
    Studentized: r_i^T S_i^-1 r_i under the residual's own covariance S_i = C_i - G_i P G_i^T for
    a fitted direction, C_i + G_i P G_i^T for the others (C_i = W_i^-1). A bright star the fit
    leans on leaves a small residual even when its centroid is biased (the fit follows it):
    judged by r_i^T W_i r_i alone it would pass any screen. Where S_i is degenerate (the
    direction alone sets the fit, det S_i < LEVERAGE_FLOOR det C_i) it is r_i^T W_i r_i.
    """
    body = np.ascontiguousarray(body, dtype=float).reshape(-1, 3)
    n = body.shape[0]
    if ray_cov is not None:
        cov, jac = np.ascontiguousarray(ray_cov, dtype=float).reshape(n, 3, 3), np.zeros((0, 3, 2))
    else:
        cov = np.ascontiguousarray(pixel_cov, dtype=float).reshape(n, 2, 2)
        jac = np.ascontiguousarray(jacobian, dtype=float).reshape(n, 3, 2)
    used = np.ones(n, np.bool_) if used is None else np.ascontiguousarray(used, dtype=np.bool_)
    rotation, covariance, loss, chi2, angle = refine_kernel(
        np.ascontiguousarray(rotation, dtype=float), body, np.ascontiguousarray(ref, dtype=float).reshape(-1, 3),
        cov, jac, used, int(iterations))
    return AttitudeSolution(matrix_to_quaternion(rotation), rotation, covariance, loss), chi2, angle


@njit(cache=True)
def refine_kernel(rotation, body, ref, cov, jac, used, iterations):
    """
    refine_with_covariances' loops, scalar arithmetic (no temporaries).

    cov: (N, 3, 3) ray covariances when jac is empty, else (N, 2, 2) pixel covariances mapped
    by jac (N, 3, 2). Returns the rotation, the covariance (inverse information of the used
    directions, 3x3), the loss (half their chi^2), the studentized chi^2 (N,) and the residual
    angles (N,) [rad].
    """
    n = body.shape[0]
    basis = np.empty((n, 2, 3))  # e1, e2 per direction
    weight = np.empty((n, 3))  # W00, W01, W11
    for i in range(n):
        bx, by, bz = body[i, 0], body[i, 1], body[i, 2]
        if abs(bz) < 0.9:  # e1 = b x z
            ex, ey, ez = by, -bx, 0.0
        else:  # e1 = b x x
            ex, ey, ez = 0.0, bz, -by
        norm = math.sqrt(ex * ex + ey * ey + ez * ez)
        ex, ey, ez = ex / norm, ey / norm, ez / norm
        basis[i, 0, 0], basis[i, 0, 1], basis[i, 0, 2] = ex, ey, ez
        basis[i, 1, 0], basis[i, 1, 1], basis[i, 1, 2] = by * ez - bz * ey, bz * ex - bx * ez, bx * ey - by * ex
        a00 = a01 = a11 = 0.0
        if jac.shape[0] == 0:  # E^T cov E
            for r in range(3):
                for c in range(3):
                    v = cov[i, r, c]
                    a00 += basis[i, 0, r] * v * basis[i, 0, c]
                    a01 += basis[i, 0, r] * v * basis[i, 1, c]
                    a11 += basis[i, 1, r] * v * basis[i, 1, c]
        else:  # M C M^T with M = E^T J (2x2)
            m00 = m01 = m10 = m11 = 0.0
            for r in range(3):
                m00 += basis[i, 0, r] * jac[i, r, 0]
                m01 += basis[i, 0, r] * jac[i, r, 1]
                m10 += basis[i, 1, r] * jac[i, r, 0]
                m11 += basis[i, 1, r] * jac[i, r, 1]
            cxx, cxy, cyy = cov[i, 0, 0], 0.5 * (cov[i, 0, 1] + cov[i, 1, 0]), cov[i, 1, 1]
            a00 = m00 * m00 * cxx + 2.0 * m00 * m01 * cxy + m01 * m01 * cyy
            a01 = m00 * m10 * cxx + (m00 * m11 + m01 * m10) * cxy + m01 * m11 * cyy
            a11 = m10 * m10 * cxx + 2.0 * m10 * m11 * cxy + m11 * m11 * cyy
        det = a00 * a11 - a01 * a01
        weight[i, 0], weight[i, 1], weight[i, 2] = a11 / det, -a01 / det, a00 / det
    info = np.zeros((3, 3))
    grad = np.zeros(3)
    chi2 = np.zeros(n)
    angle = np.zeros(n)
    residual = np.zeros((n, 2))
    gmat = np.zeros((n, 2, 3))
    rot = rotation.copy()
    for step in range(iterations + 1):
        info[:, :] = 0.0
        grad[:] = 0.0
        for i in range(n):
            # p = R^T r
            px = rot[0, 0] * ref[i, 0] + rot[1, 0] * ref[i, 1] + rot[2, 0] * ref[i, 2]
            py = rot[0, 1] * ref[i, 0] + rot[1, 1] * ref[i, 1] + rot[2, 1] * ref[i, 2]
            pz = rot[0, 2] * ref[i, 0] + rot[1, 2] * ref[i, 1] + rot[2, 2] * ref[i, 2]
            dx, dy, dz = body[i, 0] - px, body[i, 1] - py, body[i, 2] - pz
            ex, ey, ez = basis[i, 0, 0], basis[i, 0, 1], basis[i, 0, 2]
            fx, fy, fz = basis[i, 1, 0], basis[i, 1, 1], basis[i, 1, 2]
            r0 = ex * dx + ey * dy + ez * dz
            r1 = fx * dx + fy * dy + fz * dz
            w00, w01, w11 = weight[i, 0], weight[i, 1], weight[i, 2]
            wr0 = w00 * r0 + w01 * r1
            wr1 = w01 * r0 + w11 * r1
            chi2[i] = r0 * wr0 + r1 * wr1
            # Rows of E^T [p]x: (e x p)^T and (f x p)^T.
            g0x, g0y, g0z = ey * pz - ez * py, ez * px - ex * pz, ex * py - ey * px
            g1x, g1y, g1z = fy * pz - fz * py, fz * px - fx * pz, fx * py - fy * px
            if step == iterations:
                dot = body[i, 0] * px + body[i, 1] * py + body[i, 2] * pz
                angle[i] = math.acos(min(1.0, max(-1.0, dot)))
                residual[i, 0], residual[i, 1] = r0, r1
                gmat[i, 0, 0], gmat[i, 0, 1], gmat[i, 0, 2] = g0x, g0y, g0z
                gmat[i, 1, 0], gmat[i, 1, 1], gmat[i, 1, 2] = g1x, g1y, g1z
            if not used[i]:
                continue
            grad[0] += g0x * wr0 + g1x * wr1
            grad[1] += g0y * wr0 + g1y * wr1
            grad[2] += g0z * wr0 + g1z * wr1
            # W G columns, then G^T (W G).
            h0x, h0y, h0z = w00 * g0x + w01 * g1x, w00 * g0y + w01 * g1y, w00 * g0z + w01 * g1z
            h1x, h1y, h1z = w01 * g0x + w11 * g1x, w01 * g0y + w11 * g1y, w01 * g0z + w11 * g1z
            info[0, 0] += g0x * h0x + g1x * h1x
            info[0, 1] += g0x * h0y + g1x * h1y
            info[0, 2] += g0x * h0z + g1x * h1z
            info[1, 1] += g0y * h0y + g1y * h1y
            info[1, 2] += g0y * h0z + g1y * h1z
            info[2, 2] += g0z * h0z + g1z * h1z
        info[1, 0], info[2, 0], info[2, 1] = info[0, 1], info[0, 2], info[1, 2]
        if step == iterations:
            break
        delta = np.linalg.solve(info, grad)
        theta = math.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2)
        k = np.zeros((3, 3))  # [delta]x
        k[0, 1], k[0, 2], k[1, 2] = -delta[2], delta[1], -delta[0]
        k[1, 0], k[2, 0], k[2, 1] = delta[2], -delta[1], delta[0]
        if theta > 1e-12:
            step_rotation = np.eye(3) + math.sin(theta) / theta * k + (1.0 - math.cos(theta)) / theta ** 2 * (k @ k)
        else:
            step_rotation = np.eye(3) + k
        rot = rot @ step_rotation
    loss = 0.0
    for i in range(n):
        if used[i]:
            loss += 0.5 * chi2[i]
    covariance = np.linalg.inv(info)
    studentized = chi2.copy()
    for i in range(n):
        # G P G^T: the fitted attitude's error seen in this direction's tangent plane.
        q00 = q01 = q11 = 0.0
        for r in range(3):
            for c in range(3):
                q00 += gmat[i, 0, r] * covariance[r, c] * gmat[i, 0, c]
                q01 += gmat[i, 0, r] * covariance[r, c] * gmat[i, 1, c]
                q11 += gmat[i, 1, r] * covariance[r, c] * gmat[i, 1, c]
        w00, w01, w11 = weight[i, 0], weight[i, 1], weight[i, 2]
        det_w = w00 * w11 - w01 * w01
        c00, c01, c11 = w11 / det_w, -w01 / det_w, w00 / det_w  # the direction's own covariance
        sign = -1.0 if used[i] else 1.0  # a fitted direction pulled the fit towards itself
        s00, s01, s11 = c00 + sign * q00, c01 + sign * q01, c11 + sign * q11
        det_s = s00 * s11 - s01 * s01
        if det_s > LEVERAGE_FLOOR * (c00 * c11 - c01 * c01) and s00 > 0.0:
            r0, r1 = residual[i, 0], residual[i, 1]
            studentized[i] = (s11 * r0 * r0 - 2.0 * s01 * r0 * r1 + s00 * r1 * r1) / det_s
    return rot, covariance, loss, studentized, angle


def davenport_q_method(body: np.ndarray, ref: np.ndarray, sigmas: np.ndarray) -> AttitudeSolution:
    """Optimal Wahba solution by eigen-decomposition (cross-check; robust for any geometry)."""
    body, ref, sigmas = _as_inputs(body, ref, sigmas)
    weights = 1.0 / sigmas**2
    k, _ = _davenport_k(body, ref, weights)
    vals, vecs = np.linalg.eigh(k)
    return _solution(_shuster_attitude_matrix(vecs[:, -1]), body, ref, weights, sigmas)


def svd_attitude(body: np.ndarray, ref: np.ndarray, sigmas: np.ndarray) -> AttitudeSolution:
    """
    Markley's SVD solution of Wahba's problem (cross-check; no singularity at any angle).

    B = sum_i w_i b_i r_i^T = U S V^T gives A = U diag(1, 1, det U det V) V^T, the proper
    rotation closest to B (ICRS -> sensor). Inputs and result as `quest`.
    """
    body, ref, sigmas = _as_inputs(body, ref, sigmas)
    weights = 1.0 / sigmas**2
    a_matrix = svd_rotation(body, ref, weights).T
    return _solution(a_matrix, body, ref, weights, sigmas)


def svd_rotation(body: np.ndarray, ref: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """
    Sensor -> ICRS rotation of svd_attitude alone: unit vectors body (N, 3) and ref (N, 3), weights (N,) or equal.

    No input checks, no covariance: for many candidate matches (scale_free's patterns).
    """
    weighted = body if weights is None else weights[:, None] * body
    u, _, vt = np.linalg.svd(weighted.T @ ref)
    return (u @ np.diag([1.0, 1.0, np.linalg.det(u) * np.linalg.det(vt)]) @ vt).T


def quest(body: np.ndarray, ref: np.ndarray, sigmas: np.ndarray) -> AttitudeSolution:
    """
    QUEST (Shuster & Oh 1981).

    Newton-Raphson on the characteristic polynomial of K, starting at lambda = sum(weights); a
    sequential rotation is applied when the optimal rotation is near pi (QUEST's singularity);
    falls back to the q-method if Newton fails.

    body: (N, 3) sensor-frame unit vectors; ref: (N, 3) ICRS unit vectors; sigmas: (N,) 1-sigma
    direction errors [rad]. N >= 2 non-parallel vectors are needed.
    """
    body, ref, sigmas = _as_inputs(body, ref, sigmas)
    a_matrix = _quest_attitude_matrix(body, ref, sigmas)
    if a_matrix is None:
        return davenport_q_method(body, ref, sigmas)
    return _solution(a_matrix, body, ref, 1.0 / sigmas**2, sigmas)


def quest_rotation(body: np.ndarray, ref: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """
    Sensor -> ICRS rotation of `quest` alone (the same matrix), without its covariance and loss.

    For the attitudes a match is refitted with before it is accepted (verification), where
    the covariance would be computed and dropped.
    """
    body, ref, sigmas = _as_inputs(body, ref, sigmas)
    a_matrix = _quest_attitude_matrix(body, ref, sigmas)
    return davenport_q_method(body, ref, sigmas).rotation if a_matrix is None else a_matrix.T


def _quest_attitude_matrix(body: np.ndarray, ref: np.ndarray, sigmas: np.ndarray) -> np.ndarray | None:
    """Shuster's attitude matrix A (ICRS -> sensor) of quest's inputs (checked); None where the q-method must decide."""
    weights = 1.0 / sigmas**2
    unit_weights = weights / weights.sum()  # sum to 1: keeps the adjugate terms well scaled
    # Sequential rotations: QUEST's adjugate form degenerates (X and gamma -> 0) when the
    # optimal rotation is near pi, so evaluate the reference frame rotated by pi about each
    # axis as well and keep the one with the largest unnormalized |gamma|.
    best = None
    # B of the reference frame turned by pi about an axis: B with the other two columns negated
    # (exactly: each term's sign flips).
    b_unturned = (unit_weights[:, None] * body).T @ ref
    for axis in (None, 0, 1, 2):
        b_matrix = b_unturned if axis is None else b_unturned * np.where(np.arange(3) == axis, 1.0, -1.0)
        s = b_matrix + b_matrix.T
        z = _profile_z(b_matrix)
        sigma = np.trace(b_matrix)
        kappa = np.trace(_adjugate(s))
        delta = np.linalg.det(s)
        a = sigma * sigma - kappa
        b = sigma * sigma + z @ z
        c = delta + z @ s @ z
        d = z @ s @ s @ z
        lam = 1.0
        fp = 0.0
        for _ in range(50):
            f = (lam * lam - a) * (lam * lam - b) - c * lam + c * sigma - d
            fp = 2 * lam * (2 * lam * lam - a - b) - c
            step = f / fp if fp != 0 else 0.0
            lam -= step
            if abs(step) < 1e-14 * max(1.0, abs(lam)):
                break
        # A tiny slope at the root means a nearly double largest eigenvalue (two close stars,
        # unequal weights): the root's rounding error would mix in the second eigenvector.
        if abs(fp) < 1e-3:
            return None
        alpha = lam * lam - sigma * sigma + kappa
        beta = lam - sigma
        gamma = (lam + sigma) * alpha - delta
        x = (alpha * np.eye(3) + beta * s + s @ s) @ z
        # (x, gamma) = c q4 q with c = prod(lambda_max - lambda_i), the same in every frame,
        # so the largest |gamma| marks the frame where the rotation is farthest from pi.
        if best is None or abs(gamma) > abs(best[1]):
            best = (x, gamma, axis)
    x, gamma, axis = best
    norm = np.hypot(gamma, np.linalg.norm(x))
    if not np.isfinite(norm) or norm == 0.0:
        return None
    a_matrix = _shuster_attitude_matrix(np.append(x, gamma) / norm)
    if axis is not None:  # b = A' R_pi r, so A = A' R_pi
        a_matrix = a_matrix @ np.diag(np.where(np.arange(3) == axis, 1.0, -1.0))
    return a_matrix


def _as_inputs(body, ref, sigmas):
    body = np.asarray(body, dtype=float).reshape(-1, 3)
    ref = np.asarray(ref, dtype=float).reshape(-1, 3)
    sigmas = np.broadcast_to(np.asarray(sigmas, dtype=float), (body.shape[0],)).copy()
    if body.shape != ref.shape or body.shape[0] < 2:
        raise ValueError(f"need >= 2 matched vector pairs, got body {body.shape}, ref {ref.shape}")
    with np.errstate(over="ignore", divide="ignore"):
        body_norm = np.linalg.norm(body, axis=1, keepdims=True)
        ref_norm = np.linalg.norm(ref, axis=1, keepdims=True)
        weights = 1.0 / sigmas**2
    if not (np.all(np.isfinite(body)) and np.all(np.isfinite(ref)) and np.all(sigmas > 0)
            and np.all(np.isfinite(body_norm) & (body_norm > 0)) and np.all(np.isfinite(ref_norm) & (ref_norm > 0))
            and np.all(np.isfinite(weights) & (weights > 0))):
        raise ValueError("vectors must be finite and non-zero, sigmas finite and > 0 (1/sigma^2 finite)")
    return body / body_norm, ref / ref_norm, sigmas


def _adjugate(m: np.ndarray) -> np.ndarray:
    return np.array([
        [m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1], m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2],
         m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]],
        [m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2], m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0],
         m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]],
        [m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0], m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1],
         m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]],
    ])


def _solution(a_matrix: np.ndarray, body, ref, weights, sigmas) -> AttitudeSolution:
    # A (Shuster) maps ICRS -> sensor; its transpose is the sensor -> ICRS rotation we publish.
    rot = a_matrix.T
    residual = body - ref @ a_matrix.T
    loss = 0.5 * float(np.sum(weights * np.sum(residual**2, axis=1)))
    return AttitudeSolution(matrix_to_quaternion(rot), rot, attitude_covariance(body, sigmas), loss)


def _shuster_attitude_matrix(q: np.ndarray) -> np.ndarray:
    q = q / np.linalg.norm(q)
    v, s = q[:3], q[3]
    return (s * s - v @ v) * np.eye(3) + 2.0 * np.outer(v, v) - 2.0 * s * skew(v)
