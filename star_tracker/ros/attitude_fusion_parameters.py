# SPDX-License-Identifier: Apache-2.0
"""
The attitude_fusion node's parameters, each declared once (ROS-free), and the settings made of them.

`heads` names the optical heads (each a namespace relative to the node's); each head has
`mounting.<head>`, so the list of specs depends on the heads (`fusion_parameters(heads)`);
ATTITUDE_FUSION_PARAMETERS is the list for the default heads, the one config/star_tracker.yaml
shows. Everything is read-only: the heads, their mountings and the fusion are set up at
configure. `fusion_settings(values)` checks the values together and refuses bad ones with the
reason (the node's configure then fails and the node stays unconfigured).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..fuse import AlignmentConfig, FusionConfig
from ..models.attitude import quaternion_to_matrix
from ..parameter_spec import ParameterSpec, field_values
from .autostart_parameter import AUTOSTART
from .observer_parameters import OBSERVER_PARAMETERS

DEFAULT_HEADS = ("head1", "head2")
# Orientation of each default head's sensor frame in the body frame (x, y, z, w): head1's
# boresight along body +Z (its axes are the body's), head2's along body +X (a turn of 120 deg
# about (1, 1, 1): head x, y, z = body y, z, x). 90 deg apart.
DEFAULT_MOUNTINGS = {"head1": (0.0, 0.0, 0.0, 1.0), "head2": (0.5, 0.5, 0.5, 0.5)}
UNSET_MOUNTING = (0.0, 0.0, 0.0, 0.0)  # a head without a mounting of its own: refused at configure
MOUNTING_NORM_TOLERANCE = 1e-6  # largest | |q| - 1 | of an accepted mounting quaternion
HEAD_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")  # a ROS name token: a namespace and a parameter name part
RATE_SOURCES = ("heads", "topic", "none")

HEADS = ParameterSpec("heads", DEFAULT_HEADS, "the optical heads: each one's namespace, relative to this node's, "
                      "holding its camera_info, matched_stars, attitude_with_covariance and "
                      "angular_velocity_with_covariance")


def mounting_spec(head: str) -> ParameterSpec:
    """Return the `mounting.<head>` parameter: the head's sensor frame's orientation in the body frame."""
    return ParameterSpec(f"mounting.{head}", DEFAULT_MOUNTINGS.get(head, UNSET_MOUNTING),
                         "orientation of the head's sensor frame in the body frame (the tf2 transform body -> head "
                         "optical frame), unit quaternion x, y, z, w; all zero = not set (refused)")


FRAME_PARAMETERS = [
    ParameterSpec("frame_id", "icrs", "parent (inertial) frame of the fused attitude"),
    ParameterSpec("body_frame_id", "body", "the spacecraft body frame: child frame of the fused attitude, frame of "
                  "its covariance, of the alignment estimates and of a body_rate input"),
]
FUSION_PARAMETERS = [
    ParameterSpec("fusion.stale_after_s", 0.3, "a head's latest solution further than this from the fused stamp "
                  "is left out (stale)", "s", 0.0, 3600.0, low_open=True, field="stale_after_s"),
    ParameterSpec("fusion.min_stars_per_head", 3, "fewest usable matched stars of a head's solution", "", 2, 10000,
                  field="min_stars_per_head"),
    ParameterSpec("fusion.max_angular_acceleration_rad_s2", 0.0, "bound on the body's angular acceleration, for "
                  "the error of bringing heads to one stamp", "rad/s^2", 0.0, 100.0,
                  field="max_angular_acceleration"),
    ParameterSpec("fusion.iterations", 2, "Gauss-Newton steps of the joint fit after its Wahba start", "", 0, 20,
                  field="iterations"),
    ParameterSpec("fusion.max_wait_s", 0.1, "after a head's solution, wait at most this long (node clock) for the "
                  "solutions of the same stamp from the heads of the last fusion before fusing; 0 = fuse at once",
                  "s", 0.0, 3600.0),
    ParameterSpec("fusion.max_residual_sigma", 5.0, "a matched star whose residual exceeds this many of its sigma is "
                  "left out (the identifier's fit left it out as an outlier)", "-", 1.0, 1000.0),
]
ALIGNMENT_PARAMETERS = [
    ParameterSpec("alignment.enabled", True, "estimate each head's mounting correction relative to the reference "
                  "head online (two or more heads)"),
    ParameterSpec("alignment.reference", "", "the head whose nominal mounting defines the body frame; \"\" = the "
                  "first of heads"),
    ParameterSpec("alignment.drift_psd_rad2_s", 2.4e-14, "random-walk spectral density of each correction per axis "
                  "(docs/FUSION.md, Tuning drift_psd)", "rad^2/s", 0.0, 1.0, field="drift_psd"),
    ParameterSpec("alignment.initial_sigma_rad", 2.9e-4, "prior 1-sigma of each correction per axis (2.9e-4 = 60 "
                  "arcsec): how well the mountings are known before flight data", "rad", 0.0, 1.0, low_open=True,
                  field="initial_sigma_rad"),
    ParameterSpec("alignment.gate_probability", 1e-6, "chance that a consistent alignment update is rejected by its "
                  "chi^2 gate", "-", 0.0, 1.0, low_open=True, high_open=True, field="gate_probability"),
    ParameterSpec("alignment.harmonic_period_s", 0.0, "period of the heads' periodic thermo-elastic drift, modelled as "
                  "a Fourier series beside the random walk (the orbital period); 0 = no periodic term "
                  "(docs/FUSION.md, Orbit-periodic drift)", "s", 0.0, 1e9, field="harmonic_period_s"),
    ParameterSpec("alignment.harmonics", 1, "harmonics of harmonic_period_s in the periodic term", "", 1, 8,
                  field="harmonics"),
    ParameterSpec("alignment.harmonic_sigma_rad", 4.85e-5, "prior 1-sigma of each periodic amplitude per axis "
                  "(4.85e-5 = 10 arcsec)", "rad", 0.0, 1.0, low_open=True, field="harmonic_sigma_rad"),
]
RATE_PARAMETERS = [
    ParameterSpec("body_rate.source", "heads", "the body rate that brings heads to the fused stamp: heads = the "
                  "newest angular_velocity_with_covariance of any head, turned to the body frame; topic = the "
                  "body_rate input (body frame); none = a body at rest", choices=RATE_SOURCES),
    ParameterSpec("body_rate.max_age_s", 0.5, "a rate stamped further than this from the fused stamp is not used",
                  "s", 0.0, 3600.0, low_open=True),
    ParameterSpec("body_rate.unknown_sigma_rad_s", 0.0175, "without a usable rate (heads, topic): 1-sigma per axis "
                  "of the unknown rate about zero, which the fit marginalises", "rad/s", 0.0, 10.0, low_open=True),
]
OTHER_PARAMETERS = [*FRAME_PARAMETERS, *FUSION_PARAMETERS, *ALIGNMENT_PARAMETERS, *RATE_PARAMETERS,
                    *OBSERVER_PARAMETERS, AUTOSTART]


def fusion_parameters(heads) -> list[ParameterSpec]:
    """Return the node's specs for these heads, in declaration order (mountings only for well-formed names)."""
    return [HEADS, *(mounting_spec(head) for head in heads if HEAD_NAME.match(head)), *OTHER_PARAMETERS]


ATTITUDE_FUSION_PARAMETERS = fusion_parameters(DEFAULT_HEADS)


@dataclass(frozen=True)
class FusionSettings:
    """
    What the node runs, checked.

    heads: the heads' names (configured order); mountings: head -> (3, 3) rotation body ->
    head (M, v_head = M v_body); fusion: the FusionConfig; alignment: its AlignmentConfig (the
    reference first) or None; frame_id, body_frame_id; rate_source: one of RATE_SOURCES;
    rate_max_age_s [s]; unknown_rate_sigma [rad/s]; max_residual_sigma [-]; max_wait_s [s].
    """

    heads: tuple[str, ...]
    mountings: dict[str, np.ndarray]
    fusion: FusionConfig
    alignment: AlignmentConfig | None
    frame_id: str
    body_frame_id: str
    rate_source: str
    rate_max_age_s: float
    unknown_rate_sigma: float
    max_residual_sigma: float
    max_wait_s: float


def mounting_matrix(head: str, quaternion) -> np.ndarray:
    """
    Return the body -> head rotation M of `mounting.<head>` (the head frame's orientation in the body frame).

    Raises ValueError naming the parameter for anything but 4 finite values of unit norm.
    """
    q = np.asarray(quaternion if quaternion is not None else [], dtype=float)
    name = f"mounting.{head}"
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError(f"{name} must be 4 finite values x, y, z, w, got {q.tolist()}")
    norm = float(np.linalg.norm(q))
    if not np.all(q == 0.0) and abs(norm - 1.0) > MOUNTING_NORM_TOLERANCE:
        raise ValueError(f"{name}={q.tolist()} is not a unit quaternion (norm {norm:.9f}, must be 1 within "
                         f"{MOUNTING_NORM_TOLERANCE:g}: give at least 7 digits)")
    if norm == 0.0:
        raise ValueError(f"{name} is not set: give the head's orientation in the body frame as a unit quaternion "
                         "x, y, z, w")
    return quaternion_to_matrix(q).T  # R(q) maps head to body vectors; M maps body to head


def fusion_settings(values: dict) -> FusionSettings:
    """Check the declared values together and return the settings; ValueError with every reason found first."""
    heads = tuple(values.get("heads") or ())
    if not heads:
        raise ValueError("heads is empty: name at least one head (its namespace), e.g. heads: [head1, head2]")
    bad = [head for head in heads if not HEAD_NAME.match(head)]
    if bad:
        raise ValueError(f"heads {bad} are not names of one letter then letters, digits or underscores")
    if len(set(heads)) != len(heads):
        raise ValueError(f"heads {list(heads)} name a head twice")
    mountings = {head: mounting_matrix(head, values.get(f"mounting.{head}")) for head in heads}
    problems = [problem for problem in (spec.problem(values[spec.name]) for spec in OTHER_PARAMETERS) if problem]
    if problems:  # the open ends of ranges (a ROS descriptor's range is closed), the choices
        raise ValueError("; ".join(problems))
    fusion = FusionConfig(heads, **field_values(FUSION_PARAMETERS, values))
    alignment = None
    if values["alignment.enabled"] and len(heads) > 1:
        reference = values["alignment.reference"] or heads[0]
        if reference not in heads:
            raise ValueError(f"alignment.reference={reference!r} is not one of heads {list(heads)}")
        ordered = (reference, *(head for head in heads if head != reference))
        alignment = AlignmentConfig(ordered, **field_values(ALIGNMENT_PARAMETERS, values),
                                    max_angular_acceleration=fusion.max_angular_acceleration)
    for name in ("frame_id", "body_frame_id"):
        if not values[name]:
            raise ValueError(f"{name} is empty")
    return FusionSettings(heads, mountings, fusion, alignment, values["frame_id"], values["body_frame_id"],
                          values["body_rate.source"], values["body_rate.max_age_s"],
                          values["body_rate.unknown_sigma_rad_s"], values["fusion.max_residual_sigma"],
                          values["fusion.max_wait_s"])
