# SPDX-License-Identifier: Apache-2.0
"""
Attitude representations.

Quaternions, rotation matrices and rotation vectors, boresight RA/Dec/roll, and the
small-angle error between two attitudes. Estimation from measured directions is in
attitude_estimation.

Quaternions are (x, y, z, w) like ROS `geometry_msgs/Quaternion`, unit norm, w >= 0.
An attitude quaternion q is the orientation of the sensor frame in ICRS: it maps
sensor-frame vectors to ICRS, v_icrs = R(q) v_sensor.
"""
from __future__ import annotations

import math

import numpy as np

ARCSEC = np.pi / (180.0 * 3600.0)


def normalize_quaternion(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(norm) & (norm > 0.0)):
        raise ValueError("quaternions must be finite and non-zero")
    q = q / norm
    return np.where(q[..., 3:4] < 0.0, -q, q)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix R (3x3) of the (x, y, z, w) quaternion: v_parent = R v_child."""
    x, y, z, w = normalize_quaternion(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quaternion(rot: np.ndarray) -> np.ndarray:
    """(x, y, z, w) quaternion of a rotation matrix (Shepperd's method, stable everywhere)."""
    m = np.asarray(rot, dtype=float).tolist()  # Python floats: this runs once per frame, fast
    trace = m[0][0] + m[1][1] + m[2][2]
    candidates = (m[0][0], m[1][1], m[2][2], trace)
    i = max(range(4), key=candidates.__getitem__)
    if i == 3:
        w = 0.5 * math.sqrt(1.0 + trace)
        x = (m[2][1] - m[1][2]) / (4 * w)
        y = (m[0][2] - m[2][0]) / (4 * w)
        z = (m[1][0] - m[0][1]) / (4 * w)
    elif i == 0:
        x = 0.5 * math.sqrt(1.0 + 2 * m[0][0] - trace)
        w = (m[2][1] - m[1][2]) / (4 * x)
        y = (m[0][1] + m[1][0]) / (4 * x)
        z = (m[0][2] + m[2][0]) / (4 * x)
    elif i == 1:
        y = 0.5 * math.sqrt(1.0 + 2 * m[1][1] - trace)
        w = (m[0][2] - m[2][0]) / (4 * y)
        x = (m[0][1] + m[1][0]) / (4 * y)
        z = (m[1][2] + m[2][1]) / (4 * y)
    else:
        z = 0.5 * math.sqrt(1.0 + 2 * m[2][2] - trace)
        w = (m[1][0] - m[0][1]) / (4 * z)
        x = (m[0][2] + m[2][0]) / (4 * z)
        y = (m[1][2] + m[2][1]) / (4 * z)
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    sign = 1.0 if w >= 0 else -1.0  # w >= 0, as normalize_quaternion
    return np.array([x, y, z, w]) * (sign / norm)


def rotation_vector_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation by |rotvec| [rad] about rotvec's direction."""
    x, y, z = (float(v) for v in np.asarray(rotvec, dtype=float).reshape(3))  # scalars: once per frame, fast
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        return np.array([[1.0, -z, y], [z, 1.0, -x], [-y, x, 1.0]])
    s, c = math.sin(angle), 1.0 - math.cos(angle)
    x, y, z = x / angle, y / angle, z / angle
    # I + sin K + (1 - cos) K^2 with K = [axis]x and K^2 = axis axis^T - I
    return np.array([[1.0 + c * (x * x - 1.0), c * x * y - s * z, c * x * z + s * y],
                     [c * x * y + s * z, 1.0 + c * (y * y - 1.0), c * y * z - s * x],
                     [c * x * z - s * y, c * y * z + s * x, 1.0 + c * (z * z - 1.0)]])


def matrix_to_rotation_vector(rot: np.ndarray) -> np.ndarray:
    """Inverse of rotation_vector_to_matrix (angle in [0, pi])."""
    q = matrix_to_quaternion(rot)
    sin_half = np.linalg.norm(q[:3])
    angle = 2.0 * np.arctan2(sin_half, q[3])
    if sin_half < 1e-15:
        return 2.0 * q[:3]
    return q[:3] / sin_half * angle


def skew(v: np.ndarray) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def radec_roll_to_matrix(ra: float, dec: float, roll: float) -> np.ndarray:
    """
    Sensor-to-ICRS rotation for a boresight (+Z) at (ra, dec) [rad] and a roll [rad].

    roll = 0 puts image "up" (-Y, toward smaller row numbers) toward celestial north; a
    positive roll turns the camera about its boresight by the right-hand rule about +Z.
    """
    z = np.array([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])
    north = np.array([0.0, 0.0, 1.0])
    east = np.cross(north, z)
    if np.linalg.norm(east) < 1e-9:  # boresight at a pole: pick the x axis as "east"
        east = np.array([1.0, 0.0, 0.0]) if dec < 0 else np.array([0.0, 1.0, 0.0])
    east /= np.linalg.norm(east)
    up = np.cross(z, east)
    # With up = -Y and +Z forward, +X = Y x Z = (-up) x z = east seen from inside the sphere
    # is mirrored on the sky as in any camera image: x = -up x z.
    y_axis = -up
    x_axis = np.cross(y_axis, z)
    base = np.stack([x_axis, y_axis, z], axis=1)
    return base @ rotation_vector_to_matrix(np.array([0.0, 0.0, roll]))


def matrix_to_radec_roll(rot: np.ndarray) -> tuple[float, float, float]:
    """Inverse of radec_roll_to_matrix: boresight RA, Dec and roll [rad]."""
    z = rot[:, 2]
    ra = float(np.mod(np.arctan2(z[1], z[0]), 2 * np.pi))
    dec = float(np.arcsin(np.clip(z[2], -1.0, 1.0)))
    base = radec_roll_to_matrix(ra, dec, 0.0)
    rel = base.T @ rot
    roll = float(np.arctan2(rel[1, 0], rel[0, 0]))
    return ra, dec, roll


def attitude_error(rot_est: np.ndarray, rot_true: np.ndarray) -> tuple[float, float, float]:
    """
    Small-angle error of an estimate in the sensor frame [rad].

    Returns (cross_boresight, roll, total): the rotation R_true^T R_est as a rotation
    vector; cross-boresight = norm of its X, Y part, roll = |Z part|.
    """
    rotvec = matrix_to_rotation_vector(rot_true.T @ rot_est)
    return float(np.hypot(rotvec[0], rotvec[1])), float(abs(rotvec[2])), float(np.linalg.norm(rotvec))
