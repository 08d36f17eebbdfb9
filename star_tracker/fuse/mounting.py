# SPDX-License-Identifier: Apache-2.0
"""
A head's mounting on the body, its small alignment correction, and the body attitude a head implies.

Mounting M: body -> head (v_head = M v_body). A correction c (body-frame rotation vector
[rad]) says the head, as actually mounted, is turned by c about the body axes from its
nominal mounting: head -> body is exp([c]x) M^T, so the corrected mounting is
M exp(-[c]x). A head's attitude R_head (head -> ICRS) then implies the body attitude
R_body = R_head M exp(-[c]x) (body -> ICRS); its covariance moves from the head frame to the
body frame as M^T P M.
"""
from __future__ import annotations

import numpy as np

from ..models.attitude import rotation_vector_to_matrix


def corrected_mounting(mounting: np.ndarray, correction: np.ndarray) -> np.ndarray:
    """Return the body -> head rotation M exp(-[c]x) of a nominal mounting M and a body-frame correction c [rad]."""
    return np.asarray(mounting, dtype=float) @ rotation_vector_to_matrix(-np.asarray(correction, dtype=float))


def implied_body_attitude(head_rotation: np.ndarray, head_covariance: np.ndarray,
                          mounting: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the body attitude a head's own attitude implies, and its covariance.

    head_rotation: head -> ICRS; head_covariance: head frame [rad^2]; mounting: body -> head
    (corrected or nominal). Returns (body -> ICRS rotation, body-frame covariance [rad^2]).
    """
    mounting = np.asarray(mounting, dtype=float)
    return np.asarray(head_rotation, dtype=float) @ mounting, mounting.T @ np.asarray(head_covariance) @ mounting
