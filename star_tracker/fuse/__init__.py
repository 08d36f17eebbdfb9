# SPDX-License-Identifier: Apache-2.0
"""
Multi-head fusion: several optical heads' matched stars in one body attitude, and their online inter-head alignment.

ROS-free; see docs/FUSION.md.
"""
from .alignment import AlignmentConfig, AlignmentEstimate, AlignmentFilter, AlignmentSample
from .joint_fit import HeadRays, JointFit, fit_heads
from .mounting import corrected_mounting, implied_body_attitude, rotation_problem
from .records import BodyRate, FusedAttitude, HeadObservation, HeadResidual

__all__ = [
    "AlignmentConfig", "AlignmentEstimate", "AlignmentFilter", "AlignmentSample", "BodyRate", "FusedAttitude",
    "HeadObservation", "HeadResidual", "HeadRays", "JointFit", "corrected_mounting", "fit_heads",
    "implied_body_attitude", "rotation_problem",
]
