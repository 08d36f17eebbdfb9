# SPDX-License-Identifier: Apache-2.0
"""
Online inter-head alignment: each head's mounting correction relative to a reference head, by a Kalman filter.

State: the corrections c_h (body-frame rotation vectors [rad], mounting.py's convention) of
every head but the reference, whose correction is 0 by definition: the heads are aligned to
one another, and the body frame is the reference head's nominal mounting (stars alone cannot
tell where the body is). Process: each c_h a random walk, E[dc dc^T] = drift_psd dt I per
head, which lets the estimate follow a slow thermo-elastic drift. Measurement: in a frame
where two or more heads solved their attitude, each head's attitude implies a body attitude
(R_head M_h, nominal mounting); brought to one stamp with the body rate and corrected by the
current estimate, an anchor head a (the reference if present) and each other head k disagree
by nu_k = log((B_a exp(-[c_a]x))^T B_k exp(-[c_k]x)) = (c_k - c_a) - (ĉ_k - ĉ_a) + n_k - n_a,
where n_h is head h's attitude error in the body frame (M^T P_head M), plus the body-rate
error times the heads' stamp difference. Updates whose innovation fails a chi^2 gate (a
wrong identification, a jump) are rejected and counted.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple, Sequence

import numpy as np
from scipy.stats import chi2

from ..models.attitude import ARCSEC, matrix_to_rotation_vector, rotation_vector_to_matrix
from .checks import covariance_problem, rate_problem, rotation_problem
from .records import BodyRate
from .time_alignment import acceleration_covariance, propagate_attitude, stamp_difference_s


@dataclass(frozen=True)
class AlignmentConfig:
    """
    Settings of the alignment filter.

    heads: every head's name, the first is the reference; drift_psd: random-walk spectral
    density of each correction per axis [rad^2/s] (the tuning parameter: see docs/FUSION.md);
    initial_sigma_rad: prior 1-sigma of each correction per axis [rad]; gate_probability:
    chance that a consistent update is rejected by the chi^2 gate; max_angular_acceleration:
    bound on the body's angular acceleration [rad/s^2] for bringing heads to one stamp.
    """

    heads: tuple[str, ...]
    drift_psd: float
    initial_sigma_rad: float = 60.0 * ARCSEC
    gate_probability: float = 1e-6
    max_angular_acceleration: float = 0.0

    def __post_init__(self):
        if len(self.heads) < 2 or len(set(self.heads)) != len(self.heads):
            raise ValueError(f"need two or more distinct heads, got {self.heads}")
        if not (self.drift_psd >= 0.0 and self.initial_sigma_rad > 0.0 and 0.0 < self.gate_probability < 1.0
                and self.max_angular_acceleration >= 0.0):
            raise ValueError(f"invalid alignment settings: {self}")


class AlignmentSample(NamedTuple):
    """
    One head's own solution for an alignment update.

    head: name; stamp_ns: its mid-exposure stamp [ns]; body_rotation: (3, 3) body -> ICRS
    implied with its nominal mounting (R_head M); covariance: (3, 3) of that, body frame [rad^2].
    """

    head: str
    stamp_ns: int
    body_rotation: np.ndarray
    covariance: np.ndarray


class AlignmentEstimate(NamedTuple):
    """correction: (3,) body-frame rotation vector [rad]; covariance: (3, 3) [rad^2]."""

    correction: np.ndarray
    covariance: np.ndarray


@dataclass
class AlignmentCounters:
    """updates: applied; gated: rejected by the chi^2 gate; out_of_order: stamps not after the last update's."""

    updates: int = 0
    gated: int = 0
    out_of_order: int = 0


@lru_cache(maxsize=64)
def gate_threshold(probability: float, degrees_of_freedom: int) -> float:
    """Return the chi^2 value a consistent innovation exceeds with the given probability."""
    return float(chi2.isf(probability, degrees_of_freedom))


class AlignmentFilter:
    """Recursive estimate of every head's mounting correction relative to the reference head (module docstring)."""

    def __init__(self, config: AlignmentConfig):
        self.config = config
        self.counters = AlignmentCounters()
        self._index = {head: i - 1 for i, head in enumerate(config.heads)}  # reference: -1, no state
        size = 3 * (len(config.heads) - 1)
        self._state = np.zeros(size)
        self._covariance = np.eye(size) * config.initial_sigma_rad ** 2
        self._last_stamp_ns: int | None = None

    @property
    def reference(self) -> str:
        return self.config.heads[0]

    def estimate(self, head: str) -> AlignmentEstimate:
        """Return the head's correction and its covariance (zero for the reference)."""
        i = self._block(head)
        if i is None:
            return AlignmentEstimate(np.zeros(3), np.zeros((3, 3)))
        return AlignmentEstimate(self._state[i].copy(), self._covariance[i, i].copy())

    def joint_covariance(self, heads: Sequence[str]) -> np.ndarray:
        """Return the (3n, 3n) covariance [rad^2] of the given heads' corrections, cross terms included."""
        out = np.zeros((3 * len(heads), 3 * len(heads)))
        for a, head_a in enumerate(heads):
            for b, head_b in enumerate(heads):
                i, j = self._block(head_a), self._block(head_b)
                if i is not None and j is not None:
                    out[3 * a:3 * a + 3, 3 * b:3 * b + 3] = self._covariance[i, j]
        return out

    def _block(self, head: str) -> slice | None:
        if head not in self._index:
            raise ValueError(f"head {head!r} is not one of the alignment filter's {self.config.heads}")
        i = self._index[head]
        return None if i < 0 else slice(3 * i, 3 * i + 3)

    def update(self, stamp_ns: int, samples: Sequence[AlignmentSample], body_rate: BodyRate | None = None) -> bool:
        """
        Update the corrections from two or more heads' own solutions, brought to stamp_ns [ns] with body_rate.

        Returns True when applied; False (and counted) when the stamp is not after the last
        update's or the chi^2 gate rejects the innovation. Raises ValueError for fewer than two
        distinct heads, an unknown head, a sample that is not a rotation with a positive
        definite covariance, or an unusable rate.
        """
        body_rate = BodyRate.at_rest() if body_rate is None else body_rate
        self._check(samples, body_rate)
        if self._last_stamp_ns is not None and stamp_ns <= self._last_stamp_ns:
            self.counters.out_of_order += 1
            return False
        self._predict(stamp_ns)
        ordered = sorted(samples, key=lambda s: self._index[s.head])  # reference (if present) first: the anchor
        innovation, design, noise = self._measurement(stamp_ns, ordered, body_rate)
        innovation_covariance = design @ self._covariance @ design.T + noise
        distance = float(innovation @ np.linalg.solve(innovation_covariance, innovation))
        if distance > gate_threshold(self.config.gate_probability, innovation.size):
            self.counters.gated += 1
            return False
        gain = np.linalg.solve(innovation_covariance, design @ self._covariance).T
        self._state = self._state + gain @ innovation
        keep = np.eye(self._state.size) - gain @ design  # Joseph form: stays symmetric positive definite
        self._covariance = keep @ self._covariance @ keep.T + gain @ noise @ gain.T
        self.counters.updates += 1
        return True

    def _check(self, samples: Sequence[AlignmentSample], body_rate: BodyRate) -> None:
        """Raise ValueError naming what makes the update's input unusable."""
        heads = [s.head for s in samples]
        if len(samples) < 2 or len(set(heads)) != len(heads):
            raise ValueError(f"an alignment update needs two or more distinct heads, got {heads}")
        for sample in samples:
            self._block(sample.head)
            problem = rotation_problem(sample.body_rotation)
            if problem:
                raise ValueError(f"head {sample.head!r}: body_rotation is {problem}")
            problem = covariance_problem(sample.covariance)
            if problem:
                raise ValueError(f"head {sample.head!r}: covariance is {problem}")
        problem = rate_problem(body_rate.rate, body_rate.covariance)
        if problem:
            raise ValueError(f"body_rate: {problem}")

    def _predict(self, stamp_ns: int) -> None:
        if self._last_stamp_ns is not None:
            dt = stamp_difference_s(stamp_ns, self._last_stamp_ns)
            self._covariance = self._covariance + np.eye(self._state.size) * (self.config.drift_psd * dt)
        self._last_stamp_ns = int(stamp_ns)

    def _measurement(self, stamp_ns: int, ordered: Sequence[AlignmentSample],
                     body_rate: BodyRate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the innovation (3(n-1),), its design matrix H and noise covariance R (anchor = ordered[0])."""
        offsets = [stamp_difference_s(stamp_ns, s.stamp_ns) for s in ordered]
        corrected = []
        for sample, dt in zip(ordered, offsets):
            block = self._block(sample.head)
            correction = np.zeros(3) if block is None else self._state[block]
            corrected.append(propagate_attitude(sample.body_rotation, dt, body_rate.rate)
                             @ rotation_vector_to_matrix(-correction))
        others = len(ordered) - 1
        innovation = np.zeros(3 * others)
        design = np.zeros((3 * others, self._state.size))
        noise = np.zeros((3 * others, 3 * others))
        anchor, anchor_block = ordered[0], self._block(ordered[0].head)
        anchor_noise = anchor.covariance + acceleration_covariance(offsets[0], self.config.max_angular_acceleration)
        for k in range(others):
            sample, rows = ordered[k + 1], slice(3 * k, 3 * k + 3)
            innovation[rows] = matrix_to_rotation_vector(corrected[0].T @ corrected[k + 1])
            design[rows, self._block(sample.head)] += np.eye(3)
            if anchor_block is not None:
                design[rows, anchor_block] -= np.eye(3)
            for j in range(others):
                cols = slice(3 * j, 3 * j + 3)
                noise[rows, cols] = anchor_noise + (offsets[k + 1] - offsets[0]) * (offsets[j + 1] - offsets[0]) \
                    * body_rate.covariance
            noise[rows, rows] += sample.covariance + acceleration_covariance(offsets[k + 1],
                                                                             self.config.max_angular_acceleration)
        return innovation, design, 0.5 * (noise + noise.T)
