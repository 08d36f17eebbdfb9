# SPDX-License-Identifier: Apache-2.0
"""
The fusion stage as a ROS node drives it: add each head's observation as it comes, ask for the attitude at a stamp.

FusionState keeps each configured head's latest accepted observation. `fused_at(stamp,
rate)` takes every head whose observation lies within `stale_after_s` of the stamp, brings
its rays to the body frame (mounting, corrected by the alignment filter when one is attached)
and to the stamp (time_alignment.py), and fits one attitude to all of them (joint_fit.py),
with the rate error (shared by all heads through their stamp offsets), the alignment
uncertainty and the unmodelled acceleration marginalised. Heads left out are reported with
the reason; a head that comes back is used again (counted as re-admitted). With an
alignment filter attached, each observation's head attitude then feeds one alignment update,
at the first fusion where two or more heads have an observation not used before, so no
observation's noise is counted twice.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..models.attitude import matrix_to_quaternion
from ..models.attitude_estimation import attitude_covariance, svd_rotation
from .alignment import AlignmentFilter, AlignmentSample
from ..models.matrix_checks import rate_problem
from .joint_fit import HeadRays, fit_heads
from .mounting import corrected_mounting, implied_body_attitude
from .records import BodyRate, FusedAttitude, HeadObservation
from .screening import INVALID, TOO_FEW_STARS, UNKNOWN_HEAD, screen_observation
from .time_alignment import acceleration_covariance, propagate_rays, stamp_difference_s

OUT_OF_ORDER = "out_of_order"


@dataclass(frozen=True)
class FusionConfig:
    """
    Settings of the fusion.

    heads: the configured heads' names (the alignment filter's reference is its own first
    head); stale_after_s: largest |fused stamp - observation stamp| used [s];
    min_stars_per_head: fewest usable stars of an accepted observation; max_angular_acceleration:
    bound on the body's angular acceleration [rad/s^2] (time alignment's error);
    iterations: Gauss-Newton steps after the Wahba start.
    """

    heads: tuple[str, ...]
    stale_after_s: float = 0.3
    min_stars_per_head: int = 3
    max_angular_acceleration: float = 0.0
    iterations: int = 2

    def __post_init__(self):
        if not self.heads or len(set(self.heads)) != len(self.heads):
            raise ValueError(f"need one or more distinct heads, got {self.heads}")
        if not (self.stale_after_s > 0.0 and self.min_stars_per_head >= 2 and self.max_angular_acceleration >= 0.0
                and self.iterations >= 0):
            raise ValueError(f"invalid fusion settings: {self}")


@dataclass
class FusionCounters:
    """
    What happened to the observations, counted since start.

    accepted; rejected by kind (unknown_head, invalid, too_few_stars, out_of_order: a stamp
    not after the head's last accepted one); excluded_stars: stars left out of accepted or
    rejected observations (NaN, not unit, bad sigma); per fusion: stale (a head's latest
    observation outside the window), missing (no observation yet), readmitted (a head used
    before, left out, and used again); fused: attitudes returned; unavailable: fusions that
    failed.
    """

    accepted: int = 0
    unknown_head: int = 0
    invalid: int = 0
    too_few_stars: int = 0
    out_of_order: int = 0
    excluded_stars: int = 0
    stale: int = 0
    missing: int = 0
    readmitted: int = 0
    fused: int = 0
    unavailable: int = 0


class Admission(NamedTuple):
    """accepted; rejection: "" or its kind (a FusionCounters field name); detail: why, in words."""

    accepted: bool
    rejection: str
    detail: str


class FusionUnavailable(ValueError):
    """No fused attitude at this stamp; `dropped` maps each head to the reason it was left out."""

    def __init__(self, message: str, dropped: dict[str, str]):
        super().__init__(message)
        self.dropped = dropped


class FusionState:
    """Per-message entry point of the multi-head fusion (module docstring)."""

    def __init__(self, config: FusionConfig, alignment: AlignmentFilter | None = None):
        if alignment is not None and set(alignment.config.heads) != set(config.heads):
            raise ValueError(f"alignment heads {alignment.config.heads} differ from fusion heads {config.heads}")
        self.config = config
        self.alignment = alignment
        self.counters = FusionCounters()
        self._latest: dict[str, HeadObservation] = {}
        self._last_rejection: dict[str, str] = {}
        self._contributed: set[str] = set()  # heads used in a fusion at least once
        self._left_out: set[str] = set()  # of those, the ones left out of the last fusion
        self._unused_for_alignment: set[str] = set()

    def latest(self, head: str) -> HeadObservation | None:
        """Return the head's latest accepted observation (stars screened), None before the first."""
        return self._latest.get(head)

    def add(self, observation: HeadObservation) -> Admission:
        """Screen one head's observation and keep it as that head's latest; the verdict is counted and returned."""
        screening = screen_observation(observation, self.config.heads, self.config.min_stars_per_head)
        self.counters.excluded_stars += screening.excluded_stars
        rejection, detail = screening.rejection, screening.detail
        last = self._latest.get(observation.head)
        if not rejection and last is not None and observation.stamp_ns <= last.stamp_ns:
            rejection = OUT_OF_ORDER
            detail = f"head {observation.head!r}: stamp {observation.stamp_ns} ns is not after {last.stamp_ns} ns"
        if rejection:
            counter = {UNKNOWN_HEAD: "unknown_head", INVALID: "invalid", TOO_FEW_STARS: "too_few_stars",
                       OUT_OF_ORDER: "out_of_order"}[rejection]
            setattr(self.counters, counter, getattr(self.counters, counter) + 1)
            if observation.head in self.config.heads:
                self._last_rejection[observation.head] = detail
            return Admission(False, rejection, detail)
        self._latest[observation.head] = screening.observation
        self._last_rejection.pop(observation.head, None)
        self._unused_for_alignment.add(observation.head)
        self.counters.accepted += 1
        left_out = f"{screening.excluded_stars} stars left out" if screening.excluded_stars else ""
        return Admission(True, "", left_out)

    def fused_at(self, stamp_ns: int, body_rate: BodyRate | None = None) -> FusedAttitude:
        """
        Return the body attitude at stamp_ns [ns] from every fresh head, then feed the alignment filter.

        body_rate: the body's rate and its covariance (body frame), None for a body at rest.
        Raises FusionUnavailable (counted) when no head is fresh or the stars do not determine
        the attitude; ValueError for a stamp that is not an integer or an unusable rate.
        """
        body_rate = BodyRate.at_rest() if body_rate is None else body_rate
        if not isinstance(stamp_ns, (int, np.integer)):
            raise ValueError(f"stamp_ns must be an integer [ns], got {type(stamp_ns).__name__}")
        problem = rate_problem(body_rate.rate, body_rate.covariance)
        if problem:
            raise ValueError(f"body_rate: {problem}")
        fresh, dropped = self._select(stamp_ns)
        self.counters.readmitted += len(self._left_out.intersection(fresh))
        self._left_out = self._left_out.union(dropped).intersection(self._contributed).difference(fresh)
        self._contributed.update(fresh)
        if not fresh:
            self.counters.unavailable += 1
            raise FusionUnavailable(f"no fresh head at {stamp_ns} ns: {dropped}", dropped)
        heads, shared_covariance = self._head_rays(stamp_ns, fresh, body_rate)
        try:
            fit = fit_heads(heads, shared_covariance, self.config.iterations)
        except ValueError as error:
            self.counters.unavailable += 1
            raise FusionUnavailable(f"at {stamp_ns} ns: {error}", dropped) from error
        self._feed_alignment(stamp_ns, fresh, body_rate)
        self.counters.fused += 1
        return FusedAttitude(int(stamp_ns), fit.rotation, matrix_to_quaternion(fit.rotation), fit.covariance,
                             tuple(fresh), fit.residuals, dropped, fit.chi2)

    def _select(self, stamp_ns: int) -> tuple[dict[str, HeadObservation], dict[str, str]]:
        """Return the fresh heads' observations (config order) and, for every other head, why it is left out."""
        fresh, dropped = {}, {}
        for head in self.config.heads:
            observation = self._latest.get(head)
            rejected = self._last_rejection.get(head)
            if observation is None:
                self.counters.missing += 1
                dropped[head] = "no observation yet" + (f"; last one rejected: {rejected}" if rejected else "")
                continue
            offset = stamp_difference_s(stamp_ns, observation.stamp_ns)
            if abs(offset) > self.config.stale_after_s:
                self.counters.stale += 1
                dropped[head] = (f"stale: latest observation {offset:+.3f} s from the stamp "
                                 f"(window {self.config.stale_after_s} s)"
                                 + (f"; last one rejected: {rejected}" if rejected else ""))
                continue
            fresh[head] = observation
        return fresh, dropped

    def _head_rays(self, stamp_ns: int, fresh: dict[str, HeadObservation],
                   body_rate: BodyRate) -> tuple[list[HeadRays], np.ndarray]:
        """Return each fresh head's body-frame rays at the stamp and the shared errors' covariance (rate, alignment)."""
        aligned = [] if self.alignment is None else [h for h in fresh if h != self.alignment.reference]
        size = 3 + 3 * len(aligned)
        shared_covariance = np.zeros((size, size))
        shared_covariance[:3, :3] = body_rate.covariance
        if aligned:
            shared_covariance[3:, 3:] = self.alignment.joint_covariance(aligned, stamp_ns)
        heads = []
        for head, observation in fresh.items():
            offset = stamp_difference_s(stamp_ns, observation.stamp_ns)
            mounting = observation.mounting
            shared_map = np.zeros((3, size))
            shared_map[:, :3] = np.eye(3) * offset
            if head in aligned:
                mounting = corrected_mounting(mounting, self.alignment.estimate(head, stamp_ns).correction)
                k = 3 + 3 * aligned.index(head)
                shared_map[:, k:k + 3] = np.eye(3)
            body_rays = propagate_rays(observation.rays @ mounting, offset, body_rate.rate)  # rows M^T b
            heads.append(HeadRays(head, body_rays, observation.catalog_vectors, observation.ray_sigmas,
                                  acceleration_covariance(offset, self.config.max_angular_acceleration), shared_map))
        return heads, shared_covariance

    def _feed_alignment(self, stamp_ns: int, fresh: dict[str, HeadObservation], body_rate: BodyRate) -> None:
        """Update the alignment filter when two or more fresh heads have observations not used for it yet."""
        if self.alignment is None:
            return
        unused = [head for head in fresh if head in self._unused_for_alignment]
        if len(unused) < 2:
            return
        samples = []
        for head in unused:
            observation = fresh[head]
            if observation.head_rotation is None:  # the Wahba solution of its stars (as QUEST), Shuster's covariance
                rotation = svd_rotation(observation.rays, observation.catalog_vectors, observation.ray_sigmas ** -2.0)
                covariance = attitude_covariance(observation.rays, observation.ray_sigmas)
            else:
                rotation, covariance = observation.head_rotation, observation.head_covariance
            body_rotation, body_covariance = implied_body_attitude(rotation, covariance, observation.mounting)
            samples.append(AlignmentSample(head, observation.stamp_ns, body_rotation, body_covariance))
        self.alignment.update(stamp_ns, samples, body_rate)
        self._unused_for_alignment.difference_update(unused)
