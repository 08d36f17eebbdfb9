# SPDX-License-Identifier: Apache-2.0
"""
Multi-head fusion: several optical heads' matched stars in one body attitude, and their online inter-head alignment.

ROS-free. A node adds each head's observation (FusionState.add) and asks for the body
attitude at a stamp (FusionState.fused_at); see docs/FUSION.md.
"""
from .alignment import AlignmentConfig, AlignmentEstimate, AlignmentFilter, AlignmentSample, PeriodicDrift
from .joint_fit import HeadRays, JointFit, fit_heads
from ..models.matrix_checks import rotation_problem
from .mounting import corrected_mounting, implied_body_attitude
from .records import BodyRate, FusedAttitude, HeadObservation, HeadResidual
from .state import Admission, FusionConfig, FusionCounters, FusionState, FusionUnavailable

__all__ = [
    "Admission", "AlignmentConfig", "AlignmentEstimate", "AlignmentFilter", "AlignmentSample", "BodyRate",
    "FusedAttitude", "FusionConfig", "FusionCounters", "FusionState", "FusionUnavailable", "HeadObservation",
    "HeadResidual", "PeriodicDrift", "HeadRays", "JointFit", "corrected_mounting", "fit_heads", "implied_body_attitude",
    "rotation_problem",
]
