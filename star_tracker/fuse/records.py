# SPDX-License-Identifier: Apache-2.0
"""
The records of multi-head fusion: one head's observation, the body rate, and the fused attitude.

Frames: ICRS (the catalog's), the spacecraft body frame and each head's sensor frame (+Z
boresight, +X image right, +Y image down). A head's mounting M is the rotation body -> head,
v_head = M v_body. Attitudes are rotation matrices R with v_icrs = R v_frame; attitude
covariances are of the small-angle error dtheta in R_est = R_true exp([dtheta]x), i.e. in the
frame R maps from (body frame for the fused attitude, head frame for a head's own attitude).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np


@dataclass(frozen=True)
class HeadObservation:
    """
    What one optical head measured in one frame: its matched stars.

    head: the head's name (one of FusionConfig.heads); stamp_ns: mid-exposure stamp [ns];
    mounting: (3, 3) rotation body -> head (nominal, as configured); catalog_vectors: (M, 3)
    ICRS unit vectors of the matched catalog stars; rays: (M, 3) measured unit directions of
    the same stars in the head frame; ray_sigmas: (M,) isotropic 1-sigma direction error of
    each ray [rad] (the same in every direction perpendicular to the ray);
    head_rotation: optional (3, 3) head -> ICRS attitude the head solved itself;
    head_covariance: optional (3, 3) its small-angle error covariance, head frame [rad^2].
    Without a head attitude, the inter-head alignment solves one from the stars (Wahba, as QUEST).
    """

    head: str
    stamp_ns: int
    mounting: np.ndarray
    catalog_vectors: np.ndarray
    rays: np.ndarray
    ray_sigmas: np.ndarray
    head_rotation: np.ndarray | None = None
    head_covariance: np.ndarray | None = None


class BodyRate(NamedTuple):
    """
    The body's angular velocity relative to ICRS, used to bring observations to one stamp.

    rate: (3,) [rad/s] in the body frame; covariance: (3, 3) its error covariance [rad^2/s^2].
    """

    rate: np.ndarray
    covariance: np.ndarray

    @staticmethod
    def at_rest() -> "BodyRate":
        """Return a zero rate known exactly (a body that does not turn)."""
        return BodyRate(np.zeros(3), np.zeros((3, 3)))


class HeadResidual(NamedTuple):
    """
    How one head's stars sit on the fused attitude.

    stars: stars fitted; rms_residual_rad: RMS angle between its rays and the fused
    prediction [rad]; chi2: sum of the squared residuals over each ray's variance (2 degrees
    of freedom per star); offset: (3,) body-frame rotation [rad] that this head's stars alone
    would add to the fused attitude (a persistent non-zero offset is a misalignment);
    offset_covariance: (3, 3) the covariance of the head-alone estimate [rad^2] (ray noise
    only; the offset's scatter about zero is this minus the fused covariance).
    """

    stars: int
    rms_residual_rad: float
    chi2: float
    offset: np.ndarray
    offset_covariance: np.ndarray


@dataclass(frozen=True)
class FusedAttitude:
    """
    One body attitude from all heads.

    stamp_ns: the stamp it holds at [ns]; rotation: (3, 3) body -> ICRS; quaternion: (x, y, z,
    w) of the same; covariance: (3, 3) small-angle error covariance in the body frame [rad^2];
    heads: the heads whose stars were fitted; residuals: per contributing head; dropped: head
    -> reason for each known head left out; chi2: total over all stars (2 DOF per star).
    """

    stamp_ns: int
    rotation: np.ndarray
    quaternion: np.ndarray
    covariance: np.ndarray
    heads: tuple[str, ...]
    residuals: dict[str, HeadResidual] = field(default_factory=dict)
    dropped: dict[str, str] = field(default_factory=dict)
    chi2: float = 0.0
