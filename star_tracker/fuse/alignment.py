# SPDX-License-Identifier: Apache-2.0
"""
Online inter-head alignment: each head's mounting correction relative to a reference head, by a Kalman filter.

State: the corrections c_h (body-frame rotation vectors [rad], mounting.py's convention) of
every head but the reference, whose correction is 0 by definition: the heads are aligned to
one another, and the body frame is the reference head's nominal mounting (stars alone cannot
tell where the body is). Process: each c_h a random walk, E[dc dc^T] = drift_psd dt I per
head, which lets the estimate follow a slow thermo-elastic drift. With harmonic_period_s set
(the orbital period), each correction is c_h(t) = a_h + sum_j (s_hj sin(j w t) + k_hj cos(j w t)),
j = 1..harmonics, w = 2 pi / harmonic_period_s, t from the first update: the orbit-periodic
thermo-elastic distortion as a Fourier series (as alignment calibrations model it), a_h the
random walk and s_hj, k_hj constants with prior 1-sigma harmonic_sigma_rad; the random walk
is then left for what is not periodic and can be much smaller. Measurement: in a frame
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
from ..models.matrix_checks import covariance_problem, rate_problem, rotation_problem
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
    bound on the body's angular acceleration [rad/s^2] for bringing heads to one stamp;
    harmonic_period_s: period of the modelled periodic drift [s] (the orbital period), 0 = no
    periodic term; harmonics: how many harmonics of it; harmonic_sigma_rad: prior 1-sigma of
    their sine and cosine amplitudes per axis [rad].
    """

    heads: tuple[str, ...]
    drift_psd: float
    initial_sigma_rad: float = 60.0 * ARCSEC
    gate_probability: float = 1e-6
    max_angular_acceleration: float = 0.0
    harmonic_period_s: float = 0.0
    harmonics: int = 1
    harmonic_sigma_rad: float = 10.0 * ARCSEC

    def __post_init__(self):
        if len(self.heads) < 2 or len(set(self.heads)) != len(self.heads):
            raise ValueError(f"need two or more distinct heads, got {self.heads}")
        if not (self.drift_psd >= 0.0 and self.initial_sigma_rad > 0.0 and 0.0 < self.gate_probability < 1.0
                and self.max_angular_acceleration >= 0.0 and self.harmonic_period_s >= 0.0
                and self.harmonic_sigma_rad > 0.0 and np.isfinite(self.harmonic_period_s)
                and int(self.harmonics) == self.harmonics and 1 <= self.harmonics <= 8):
            raise ValueError(f"invalid alignment settings: {self}")

    @property
    def states_per_head(self) -> int:
        """3 (the correction), or with a periodic term 3 + 6 harmonics (its constant, sine and cosine parts)."""
        return 3 + 6 * self.harmonics if self.harmonic_period_s > 0.0 else 3


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


class PeriodicDrift(NamedTuple):
    """A head's periodic correction: sine and cosine amplitudes (harmonics, 3) each [rad], their 1-sigma likewise."""

    sine: np.ndarray
    cosine: np.ndarray
    sine_sigma: np.ndarray
    cosine_sigma: np.ndarray


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
        per_head = config.states_per_head
        self._state = np.zeros(per_head * (len(config.heads) - 1))
        prior = np.full(per_head, config.harmonic_sigma_rad ** 2)
        prior[:3] = config.initial_sigma_rad ** 2
        self._covariance = np.diag(np.tile(prior, len(config.heads) - 1))
        self._walk = np.tile(np.arange(per_head) < 3, len(config.heads) - 1)  # the states that random-walk
        self._last_stamp_ns: int | None = None
        self._epoch_ns: int | None = None  # t = 0 of the periodic term: the first update's stamp

    @property
    def reference(self) -> str:
        return self.config.heads[0]

    def estimate(self, head: str, stamp_ns: int | None = None) -> AlignmentEstimate:
        """Return the head's correction and covariance at stamp_ns [ns] (default: the last update's; 0: reference)."""
        i = self._block(head)
        if i is None:
            return AlignmentEstimate(np.zeros(3), np.zeros((3, 3)))
        basis = self._basis(stamp_ns)
        return AlignmentEstimate(basis @ self._state[i], basis @ self._covariance[i, i] @ basis.T)

    def joint_covariance(self, heads: Sequence[str], stamp_ns: int | None = None) -> np.ndarray:
        """Return the (3n, 3n) covariance [rad^2] of the given heads' corrections at stamp_ns, cross terms included."""
        basis = self._basis(stamp_ns)
        out = np.zeros((3 * len(heads), 3 * len(heads)))
        for a, head_a in enumerate(heads):
            for b, head_b in enumerate(heads):
                i, j = self._block(head_a), self._block(head_b)
                if i is not None and j is not None:
                    out[3 * a:3 * a + 3, 3 * b:3 * b + 3] = basis @ self._covariance[i, j] @ basis.T
        return out

    def periodic_drift(self, head: str) -> PeriodicDrift | None:
        """Return the head's estimated periodic term, or None without one (no harmonic period, or the reference)."""
        i = self._block(head)
        if i is None or self.config.states_per_head == 3:
            return None
        state, sigma = self._state[i], np.sqrt(np.diag(self._covariance[i, i]))
        state, sigma = state[3:].reshape(-1, 2, 3), sigma[3:].reshape(-1, 2, 3)  # per harmonic: sine, then cosine
        return PeriodicDrift(state[:, 0].copy(), state[:, 1].copy(), sigma[:, 0].copy(), sigma[:, 1].copy())

    def _basis(self, stamp_ns: int | None) -> np.ndarray:
        """Return the (3, states_per_head) map from a head's states to its correction at stamp_ns."""
        if self.config.states_per_head == 3:
            return np.eye(3)
        stamp_ns = self._last_stamp_ns if stamp_ns is None else stamp_ns
        epoch_ns = self._epoch_ns if self._epoch_ns is not None else stamp_ns
        phase = 0.0 if stamp_ns is None else \
            2.0 * np.pi * stamp_difference_s(stamp_ns, epoch_ns) / self.config.harmonic_period_s
        parts = [np.eye(3)]
        for j in range(1, self.config.harmonics + 1):
            parts += [np.eye(3) * np.sin(j * phase), np.eye(3) * np.cos(j * phase)]
        return np.hstack(parts)

    def _block(self, head: str) -> slice | None:
        if head not in self._index:
            raise ValueError(f"head {head!r} is not one of the alignment filter's {self.config.heads}")
        i, n = self._index[head], self.config.states_per_head
        return None if i < 0 else slice(n * i, n * i + n)

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
            self._covariance = self._covariance + np.diag(self._walk * (self.config.drift_psd * dt))
        if self._epoch_ns is None:
            self._epoch_ns = int(stamp_ns)
        self._last_stamp_ns = int(stamp_ns)

    def _measurement(self, stamp_ns: int, ordered: Sequence[AlignmentSample],
                     body_rate: BodyRate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the innovation (3(n-1),), its design matrix H and noise covariance R (anchor = ordered[0])."""
        offsets = [stamp_difference_s(stamp_ns, s.stamp_ns) for s in ordered]
        basis = self._basis(stamp_ns)
        corrected = []
        for sample, dt in zip(ordered, offsets):
            block = self._block(sample.head)
            correction = np.zeros(3) if block is None else basis @ self._state[block]
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
            design[rows, self._block(sample.head)] += basis
            if anchor_block is not None:
                design[rows, anchor_block] -= basis
            for j in range(others):
                cols = slice(3 * j, 3 * j + 3)
                noise[rows, cols] = anchor_noise + (offsets[k + 1] - offsets[0]) * (offsets[j + 1] - offsets[0]) \
                    * body_rate.covariance
            noise[rows, rows] += sample.covariance + acceleration_covariance(offsets[k + 1],
                                                                             self.config.max_angular_acceleration)
        return innovation, design, 0.5 * (noise + noise.T)
