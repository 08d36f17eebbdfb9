# SPDX-License-Identifier: Apache-2.0
"""
Spacecraft attitude motion profiles.

An attitude is the sensor -> ICRS rotation matrix R (v_icrs = R v_sensor). Body rates omega are
expressed in the sensor frame [rad/s], so dR/dt = R [omega x]. Times are seconds on the node's
clock (floats).

Every profile provides rotations_at(times) -> (K, 3, 3), rotation_at(t) -> (3, 3) and
angular_velocity_at(t) -> (3,). rotations_at is vectorized: the renderer calls it with tens of
sub-exposure times per frame.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import OdeSolution, solve_ivp
from scipy.spatial.transform import Rotation

from ..models.attitude import matrix_to_quaternion, normalize_quaternion, rotation_vector_to_matrix, skew


class MotionProfile(ABC):
    """Interface shared by all motion profiles (see the module docstring)."""

    @abstractmethod
    def rotations_at(self, times: np.ndarray) -> np.ndarray:
        """Sensor -> ICRS rotations (K, 3, 3) at the K times [s]."""

    def rotation_at(self, t: float) -> np.ndarray:
        """Sensor -> ICRS rotation (3, 3) at time t [s]."""
        return self.rotations_at(np.array([float(t)]))[0]

    @abstractmethod
    def angular_velocity_at(self, t: float) -> np.ndarray:
        """Body rate (3,) in the sensor frame at time t [rad/s]."""


# ---------------------------------------------------------------- helpers
# attitude.py's helpers convert one rotation at a time; scipy's Rotation (same conventions:
# xyzw Hamilton quaternions, active rotations) does the stacked (K, ...) conversions.

def as_times(times) -> np.ndarray:
    t = np.asarray(times, dtype=float).reshape(-1)
    if not np.all(np.isfinite(t)):
        raise ValueError("times must be finite")
    return t


def _exp_so3(rotvecs: np.ndarray) -> np.ndarray:
    """Rotation matrices (K, 3, 3) of rotation vectors (K, 3) [rad]."""
    return Rotation.from_rotvec(rotvecs).as_matrix()


def _right_jacobian(theta: np.ndarray) -> np.ndarray:
    """SO(3) right Jacobian: exp(theta)^T d/dt exp(theta) = [(J_r(theta) dtheta/dt) x]."""
    angle = float(np.linalg.norm(theta))
    k = skew(theta)
    a = 0.5 * np.sinc(angle / (2 * np.pi)) ** 2  # (1 - cos a) / a^2
    # (a - sin a) / a^3 cancels catastrophically at small a: use its series there.
    b = 1 / 6 - angle**2 / 120 if angle < 1e-3 else (angle - np.sin(angle)) / angle**3
    return np.eye(3) - a * k + b * (k @ k)


# ---------------------------------------------------------------- validation helpers

def checked_array(value, name: str, shape: tuple | None = None) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numeric, got {value!r}") from None
    if shape is not None and a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return a


def _float(value, name: str, positive: bool = False) -> float:
    x = checked_array(value, name, ())
    if positive and x <= 0:
        raise ValueError(f"{name} must be > 0, got {float(x)}")
    return float(x)


def checked_rotation(value, name: str = "initial_rotation") -> np.ndarray:
    r = checked_array(value, name, (3, 3))
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise ValueError(f"{name} must be a rotation matrix (orthonormal, det +1)")
    return r


def _set(obj, **values) -> None:  # assign validated fields of a frozen dataclass
    for name, value in values.items():
        object.__setattr__(obj, name, value)


# ---------------------------------------------------------------- profiles

@dataclass(frozen=True)
class ConstantRateMotion(MotionProfile):
    """
    R(t) = R0 exp([omega x] (t - t0)): a fixed attitude when omega = 0.

    initial_rotation: R0 at time t0 [s]; body_rate: omega in the sensor frame [rad/s].
    """

    initial_rotation: np.ndarray
    body_rate: np.ndarray
    t0: float = 0.0

    def rotation_at(self, t: float) -> np.ndarray:
        return self.initial_rotation @ rotation_vector_to_matrix(np.asarray(self.body_rate) * (t - self.t0))

    def rotations_at(self, times: np.ndarray) -> np.ndarray:
        """Stacked rotations (K, 3, 3) at each time (vectorized Rodrigues)."""
        dt = as_times(times) - self.t0
        return self.initial_rotation @ _exp_so3(np.multiply.outer(dt, np.asarray(self.body_rate, dtype=float)))

    def angular_velocity_at(self, t: float) -> np.ndarray:
        return np.asarray(self.body_rate, dtype=float).copy()


@dataclass(frozen=True, eq=False)
class SlewMotion(MotionProfile):
    """
    Eigen-axis slew with a trapezoidal rate profile.

    Rest at R0 until t0 + t_start; then rotation about the body-fixed axis: accelerate at
    accel_rad_s2 up to max_rate_rad_s, coast, decelerate at accel_rad_s2 (a triangular profile
    when the angle is too small to reach max_rate_rad_s); then rest at R0 exp([axis x] angle_rad).

    initial_rotation: R0, sensor -> ICRS; axis: (3,) rotation axis in the sensor frame (normalized
    here); angle_rad: signed slew angle [rad] (right-hand rule about axis); max_rate_rad_s > 0
    [rad/s]; accel_rad_s2 > 0 [rad/s^2]; t0: time origin [s]; t_start: slew start after t0 [s].
    Derived: duration_s [s] and peak_rate_rad_s [rad/s]; the slew ends at end_time [s].
    """

    initial_rotation: np.ndarray
    axis: np.ndarray
    angle_rad: float
    max_rate_rad_s: float
    accel_rad_s2: float
    t0: float = 0.0
    t_start: float = 0.0
    duration_s: float = field(init=False)
    peak_rate_rad_s: float = field(init=False)

    def __post_init__(self) -> None:
        axis = checked_array(self.axis, "axis", (3,))
        if np.linalg.norm(axis) == 0:
            raise ValueError("axis must be a non-zero vector")
        angle = _float(self.angle_rad, "angle_rad")
        accel = _float(self.accel_rad_s2, "accel_rad_s2", positive=True)
        max_rate = _float(self.max_rate_rad_s, "max_rate_rad_s", positive=True)
        # Triangular profile when ramping up to max rate and back down would overshoot the angle.
        peak = min(max_rate, np.sqrt(abs(angle) * accel))
        coast = max(0.0, (abs(angle) - peak**2 / accel) / peak) if peak > 0 else 0.0
        _set(self, initial_rotation=checked_rotation(self.initial_rotation), axis=axis / np.linalg.norm(axis),
             angle_rad=angle, accel_rad_s2=accel, max_rate_rad_s=max_rate,
             t0=_float(self.t0, "t0"), t_start=_float(self.t_start, "t_start"),
             duration_s=2 * peak / accel + coast, peak_rate_rad_s=float(peak))

    @property
    def end_time(self) -> float:
        return self.t0 + self.t_start + self.duration_s

    def _angle_and_rate(self, times) -> tuple[np.ndarray, np.ndarray]:
        """Signed angle turned [rad] and signed rate [rad/s] about the axis at each time."""
        tau = as_times(times) - self.t0 - self.t_start
        a, peak = self.accel_rad_s2, self.peak_rate_rad_s
        t_acc = peak / a
        t_coast = self.duration_s - 2 * t_acc
        t1 = np.clip(tau, 0, t_acc)  # time spent in each phase so far
        t2 = np.clip(tau - t_acc, 0, t_coast)
        t3 = np.clip(tau - t_acc - t_coast, 0, t_acc)
        angle = 0.5 * a * t1**2 + peak * t2 + peak * t3 - 0.5 * a * t3**2
        angle = np.where(tau >= self.duration_s, abs(self.angle_rad), angle)  # exact final angle
        sign = np.sign(self.angle_rad)
        return sign * angle, sign * a * (t1 - t3)

    def rotations_at(self, times: np.ndarray) -> np.ndarray:
        angle, _ = self._angle_and_rate(times)
        return self.initial_rotation @ _exp_so3(np.multiply.outer(angle, self.axis))

    def angular_velocity_at(self, t: float) -> np.ndarray:
        return self.axis * self._angle_and_rate(t)[1][0]


@dataclass(frozen=True, eq=False)
class JitterMotion(MotionProfile):
    """
    Sinusoidal jitter on top of a base profile.

    R(t) = R_base(t) exp([theta(t) x]), theta(t) = sum_i A_i sin(2 pi f_i (t - t0) + phi_i): a
    rotation vector in the sensor frame [rad]; t0 = base.t0 (0 if the base has none).

    base: any motion profile; amplitudes_rad: (N, 3) per-term, per-axis amplitudes [rad], or the
    same as N*3 flat values ((3,) is one term); frequencies_hz: (N,) [Hz], > 0; phases_rad: one
    value, (N,) per term, or (N, 3) / N*3 flat per term and axis [rad].
    angular_velocity_at is exact: omega = exp(-[theta x]) omega_base + J_r(theta) dtheta/dt.
    """

    base: MotionProfile
    amplitudes_rad: np.ndarray
    frequencies_hz: np.ndarray
    phases_rad: np.ndarray | float = 0.0

    def __post_init__(self) -> None:
        if not all(callable(getattr(self.base, m, None)) for m in ("rotations_at", "angular_velocity_at")):
            raise ValueError(f"base must be a motion profile (rotations_at, angular_velocity_at), got {self.base!r}")
        amp = checked_array(self.amplitudes_rad, "amplitudes_rad")
        if amp.size == 0 or amp.size % 3 or amp.ndim > 2 or (amp.ndim == 2 and amp.shape[1] != 3):
            raise ValueError(f"amplitudes_rad must be (N, 3) or N*3 flat values, got shape {amp.shape}")
        amp = amp.reshape(-1, 3)
        n = len(amp)
        freq = checked_array(self.frequencies_hz, "frequencies_hz").reshape(-1)
        if freq.size != n or np.any(freq <= 0):
            raise ValueError(f"frequencies_hz must be {n} value(s) > 0 (one per amplitude row), got {freq.tolist()}")
        phase = checked_array(self.phases_rad, "phases_rad")
        if phase.size in (1, n) and phase.ndim <= 1:
            phase = np.broadcast_to(phase.reshape(-1, 1), (n, 3)).copy()
        elif phase.size == 3 * n and (phase.ndim == 1 or phase.shape == (n, 3)):
            phase = phase.reshape(n, 3)
        else:
            raise ValueError(f"phases_rad must be 1, {n} or {n}x3 values, got shape {phase.shape}")
        _set(self, amplitudes_rad=amp, frequencies_hz=freq, phases_rad=phase)

    def _theta(self, times) -> tuple[np.ndarray, np.ndarray]:
        """Return theta (K, 3) [rad] and dtheta/dt (K, 3) [rad/s]."""
        omega = 2 * np.pi * self.frequencies_hz[:, None]  # (N, 1)
        arg = omega * (as_times(times) - getattr(self.base, "t0", 0.0))[:, None, None] + self.phases_rad
        return (np.sum(self.amplitudes_rad * np.sin(arg), axis=1),
                np.sum(self.amplitudes_rad * omega * np.cos(arg), axis=1))

    def rotations_at(self, times: np.ndarray) -> np.ndarray:
        return self.base.rotations_at(as_times(times)) @ _exp_so3(self._theta(times)[0])

    def angular_velocity_at(self, t: float) -> np.ndarray:
        theta, theta_dot = (x[0] for x in self._theta(t))
        omega_base = np.asarray(self.base.angular_velocity_at(t), dtype=float)
        return rotation_vector_to_matrix(theta).T @ omega_base + _right_jacobian(theta) @ theta_dot


_TUMBLE_CHUNK_S = 10.0  # integrate ahead this far at least: one solve_ivp call per chunk, not per frame
_TUMBLE_RTOL = 1e-12  # DOP853 + dense output: < 1e-10 rad over 100 s at ~1 rad/s


@dataclass(frozen=True, eq=False)
class TumbleMotion(MotionProfile):
    """
    Torque-free rigid body whose principal axes are the sensor axes.

    Euler's equations I domega/dt = (I omega) x omega with the kinematics dq/dt = q (x) (omega, 0) / 2,
    integrated with DOP853 (rtol 1e-12) and evaluated from its dense output. Integration is lazy
    and cached: it grows forward (and backward, for t < t0: the motion is time-reversible) in
    chunks of >= 10 s. The cache costs ~1 kB per integrator step, and a step is ~0.25 / |omega| s
    (~1 MB per hour at 3 deg/s). Not thread-safe.

    initial_rotation: R0 (sensor -> ICRS) at t0 [s]; initial_rate_rad_s: omega(t0) in the sensor
    frame [rad/s]; inertia_kg_m2: principal moments (Ix, Iy, Iz) about the sensor axes [kg m^2],
    > 0 and obeying the triangle inequality; max_span_s: times farther than this from t0 raise
    ValueError (a clock mix-up, e.g. epoch vs. simulation time, would otherwise integrate for hours).
    """

    initial_rotation: np.ndarray
    initial_rate_rad_s: np.ndarray
    inertia_kg_m2: np.ndarray
    t0: float = 0.0
    max_span_s: float = 86400.0
    _cache: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        inertia = checked_array(self.inertia_kg_m2, "inertia_kg_m2", (3,))
        if np.any(inertia <= 0) or np.any(2 * inertia > inertia.sum() * (1 + 1e-12)):
            raise ValueError(f"inertia_kg_m2 must be > 0 and each at most the sum of the other two, "
                             f"got {inertia.tolist()}")
        rotation = checked_rotation(self.initial_rotation)
        rate = checked_array(self.initial_rate_rad_s, "initial_rate_rad_s", (3,))
        _set(self, initial_rotation=rotation, initial_rate_rad_s=rate, inertia_kg_m2=inertia,
             t0=_float(self.t0, "t0"), max_span_s=_float(self.max_span_s, "max_span_s", positive=True))
        y0 = np.concatenate([matrix_to_quaternion(rotation), rate])
        # Solution over tau = t - t0 in [lo, hi]: step boundaries ts and their interpolants.
        self._cache.update(lo=0.0, hi=0.0, y_lo=y0, y_hi=y0, ts=[0.0], interpolants=[], solution=None)

    def _rhs(self, _tau: float, y: np.ndarray) -> np.ndarray:
        qx, qy, qz, qw, wx, wy, wz = y
        ix, iy, iz = self.inertia_kg_m2
        return np.array([0.5 * (qw * wx + qy * wz - qz * wy), 0.5 * (qw * wy + qz * wx - qx * wz),
                         0.5 * (qw * wz + qx * wy - qy * wx), -0.5 * (qx * wx + qy * wy + qz * wz),
                         (iy - iz) / ix * wy * wz, (iz - ix) / iy * wz * wx, (ix - iy) / iz * wx * wy])

    def _integrate(self, tau_from: float, tau_to: float, y: np.ndarray) -> tuple[OdeSolution, np.ndarray]:
        """Dense solution from tau_from to tau_to [s] (either direction) and the state at tau_to."""
        scale = max(float(np.linalg.norm(self.initial_rate_rad_s)), 1e-9)  # atol relative to the rate
        atol = np.array([1e-14] * 4 + [1e-14 * scale] * 3)
        result = solve_ivp(self._rhs, (tau_from, tau_to), y, method="DOP853", rtol=_TUMBLE_RTOL, atol=atol,
                           dense_output=True)
        if not result.success:
            raise RuntimeError(f"tumble integration failed: {result.message}")
        return result.sol, result.y[:, -1]

    def _states(self, times) -> np.ndarray:
        """States (7, K): quaternion xyzw and body rate, at each time."""
        tau = as_times(times) - self.t0
        if tau.size == 0:
            return np.empty((7, 0))
        if np.max(np.abs(tau)) > self.max_span_s:
            raise ValueError(f"time {self.t0 + tau[np.argmax(np.abs(tau))]} s is more than max_span_s="
                             f"{self.max_span_s} s from t0={self.t0} s")
        c = self._cache
        if c["solution"] is None or tau.max() > c["hi"]:
            sol, y_end = self._integrate(c["hi"], max(tau.max(), c["hi"] + _TUMBLE_CHUNK_S), c["y_hi"])
            c.update(hi=sol.t_max, y_hi=y_end, ts=c["ts"] + list(sol.ts[1:]),
                     interpolants=c["interpolants"] + sol.interpolants, solution=None)
        if tau.min() < c["lo"]:
            sol, y_end = self._integrate(c["lo"], min(tau.min(), c["lo"] - _TUMBLE_CHUNK_S), c["y_lo"])
            c.update(lo=sol.t_min, y_lo=y_end, ts=list(sol.ts[::-1][:-1]) + c["ts"],
                     interpolants=sol.interpolants[::-1] + c["interpolants"], solution=None)
        if c["solution"] is None:
            c["solution"] = OdeSolution(np.array(c["ts"]), c["interpolants"])
        return c["solution"](tau)

    def rotations_at(self, times: np.ndarray) -> np.ndarray:
        return Rotation.from_quat(self._states(times)[:4].T).as_matrix()

    def angular_velocity_at(self, t: float) -> np.ndarray:
        return self._states(t)[4:, 0]


@dataclass(frozen=True, eq=False)
class SampledMotion(MotionProfile):
    """
    Attitude truth supplied as samples (e.g. by a dynamics simulator).

    times: (M,) strictly increasing [s]; quaternions: (M, 4) xyzw sensor -> ICRS (normalized here,
    either sign); rates: optional (M, 3) body rates in the sensor frame [rad/s];
    max_extrapolation_s: how far past the last sample the attitude may be propagated [s].

    Between samples: slerp (a constant body rate over each interval, the short way round; exact
    for constant-rate motion). Past the last sample, up to max_extrapolation_s: constant-rate
    propagation with the last rate (the supplied one, else the last interval's slerp rate, else
    zero). Before the first sample or past the extrapolation limit: ValueError.
    angular_velocity_at: linear interpolation of the supplied rates, else the interval's slerp rate.
    append() adds samples for streaming use; times, quaternions and rates always show all samples
    (read-only views of buffers that grow by doubling). Not thread-safe.
    """

    times: np.ndarray
    quaternions: np.ndarray
    rates: np.ndarray | None = None
    max_extrapolation_s: float = 1.0
    _buffer: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        times = checked_array(self.times, "times").reshape(-1)
        m = times.size
        if m == 0 or np.any(np.diff(times) <= 0):
            raise ValueError("times must be at least one strictly increasing value")
        quats = checked_array(self.quaternions, "quaternions", (m, 4))
        if np.any(np.linalg.norm(quats, axis=1) == 0):
            raise ValueError("quaternions must be non-zero")
        rates = None if self.rates is None else checked_array(self.rates, "rates", (m, 3))
        limit = _float(self.max_extrapolation_s, "max_extrapolation_s")
        if limit < 0:
            raise ValueError(f"max_extrapolation_s must be >= 0, got {limit}")
        _set(self, max_extrapolation_s=limit)
        capacity = max(16, 2 * m)
        # Per sample: time, quaternion, rate, rotation matrix, and the rotation vector [rad] to the
        # next sample in the body frame (precomputed once so that evaluation stays cheap).
        self._buffer.update(t=np.empty(capacity), q=np.empty((capacity, 4)), r=np.empty((capacity, 3, 3)),
                            step=np.zeros((capacity, 3)), w=None if rates is None else np.empty((capacity, 3)))
        self._store(0, times, quats, rates)

    def _store(self, start: int, t: np.ndarray, q: np.ndarray, w: np.ndarray | None) -> None:
        b, stop = self._buffer, start + len(t)
        b["t"][start:stop], b["q"][start:stop] = t, normalize_quaternion(q)
        b["r"][start:stop] = Rotation.from_quat(q).as_matrix()
        if w is not None:
            b["w"][start:stop] = w
        new = Rotation.from_quat(b["q"][max(start - 1, 0):stop])  # with the previous sample, if any
        if len(new) > 1:
            b["step"][max(start - 1, 0):stop - 1] = (new[:-1].inv() * new[1:]).as_rotvec()
        views = {}
        for name, key in (("times", "t"), ("quaternions", "q"), ("rates", "w")):
            views[name] = None if b[key] is None else b[key][:stop]
            if views[name] is not None:
                views[name].flags.writeable = False
        _set(self, **views)

    def append(self, t: float, q: np.ndarray, rate: np.ndarray | None = None) -> None:
        """Add a sample: t [s] after the last sample, q xyzw, rate [rad/s] iff built with rates."""
        t = _float(t, "t")
        q = checked_array(q, "q", (4,))
        if t <= self.times[-1]:
            raise ValueError(f"t={t} must be after the last sample time {self.times[-1]}")
        if np.linalg.norm(q) == 0:
            raise ValueError("q must be non-zero")
        if (rate is None) != (self.rates is None):
            raise ValueError("rate must be given if and only if the motion was built with rates")
        rate = None if rate is None else checked_array(rate, "rate", (3,))[None]
        b, m = self._buffer, self.times.size
        if m == b["t"].size:  # full: double the buffers
            for key, value in b.items():
                if value is not None:
                    b[key] = np.concatenate([value, np.zeros_like(value)])
        self._store(m, np.array([t]), q[None], rate)

    def _check_range(self, t: np.ndarray) -> None:
        if t.size and t.min() < self.times[0]:
            raise ValueError(f"time {t.min()} s is before the first sample ({self.times[0]} s)")
        if t.size and t.max() > self.times[-1] + self.max_extrapolation_s:
            raise ValueError(f"time {t.max()} s is more than max_extrapolation_s={self.max_extrapolation_s} s "
                             f"after the last sample ({self.times[-1]} s)")

    def _last_rate(self) -> np.ndarray:
        if self.rates is not None:
            return self.rates[-1].copy()
        if self.times.size == 1:
            return np.zeros(3)
        return self._buffer["step"][self.times.size - 2] / (self.times[-1] - self.times[-2])

    def _interval(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        Return the index of the sample starting each time's interval and the time since that sample [s].

        The index is the last sample's when past it.
        """
        i = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, self.times.size - 1)
        return i, t - self.times[i]

    def rotations_at(self, times: np.ndarray) -> np.ndarray:
        t = as_times(times)
        self._check_range(t)
        b, last = self._buffer, self.times.size - 1
        i, elapsed = self._interval(t)
        nxt = np.minimum(i + 1, last)
        past = (i == last)[:, None]  # at or after the last sample: constant-rate extrapolation
        step = np.where(past, np.multiply.outer(elapsed, self._last_rate()),
                        (elapsed / np.where(nxt > i, b["t"][nxt] - b["t"][i], 1.0))[:, None] * b["step"][i])
        return b["r"][i] @ _exp_so3(step)

    def angular_velocity_at(self, t: float) -> np.ndarray:
        t = as_times(t)
        self._check_range(t)
        (i,), (elapsed,) = self._interval(t)
        if i == self.times.size - 1:
            return self._last_rate()
        span = self.times[i + 1] - self.times[i]
        if self.rates is not None:
            return self.rates[i] + elapsed / span * (self.rates[i + 1] - self.rates[i])
        return self._buffer["step"][i] / span


# ---------------------------------------------------------------- factory

# kind: (required parameters, optional parameters with defaults)
_PARAMETERS = {
    "fixed": ((), {"t0": 0.0}),
    "constant_rate": (("body_rate_rad_s",), {"t0": 0.0}),
    "slew": (("axis", "angle_rad", "max_rate_rad_s", "accel_rad_s2"), {"t0": 0.0, "t_start": 0.0}),
    "tumble": (("initial_rate_rad_s", "inertia_kg_m2"), {"t0": 0.0}),
    "jitter": (("amplitudes_rad", "frequencies_hz"), {"body_rate_rad_s": (0.0, 0.0, 0.0), "phases_rad": 0.0,
                                                      "t0": 0.0}),
}


def motion_from_parameters(kind: str, initial_rotation, **kwargs) -> MotionProfile:
    """
    Build a motion profile from plain values (floats and flat lists, as ROS parameters give them).

    initial_rotation: 3x3 sensor -> ICRS rotation at t0. Every kind takes t0 [s] (default 0).
      "fixed": no other parameter.
      "constant_rate": body_rate_rad_s (3 values, sensor frame [rad/s]).
      "slew": axis (3 values, sensor frame), angle_rad [rad], max_rate_rad_s [rad/s],
              accel_rad_s2 [rad/s^2], t_start [s] after t0 (default 0); see SlewMotion.
      "tumble": initial_rate_rad_s (3 values [rad/s]), inertia_kg_m2 (3 principal moments
              about the sensor axes [kg m^2]); see TumbleMotion.
      "jitter": over a constant-rate base: body_rate_rad_s (3 values [rad/s], default 0),
              amplitudes_rad (3N flat values: x, y, z of term 1, then term 2, ... [rad]),
              frequencies_hz (N values [Hz]), phases_rad (1, N or 3N values [rad], default 0);
              see JitterMotion.
    Raises ValueError naming the problem (unknown kind, missing/unknown parameter, bad value).
    """
    if kind not in _PARAMETERS:
        raise ValueError(f"unknown motion kind {kind!r}; expected one of {sorted(_PARAMETERS)}")
    required, optional = _PARAMETERS[kind]
    missing = [name for name in required if name not in kwargs]
    unknown = sorted(set(kwargs) - set(required) - set(optional))
    if missing or unknown:
        raise ValueError(f"motion kind {kind!r}: " + "; ".join(
            ([f"missing parameter(s) {missing}"] if missing else []) +
            ([f"unknown parameter(s) {unknown}"] if unknown else [])) +
            f" (accepts {list(required) + list(optional)})")
    p = {**optional, **kwargs}
    rotation, t0 = checked_rotation(initial_rotation), _float(p.pop("t0"), "t0")
    if kind == "fixed":
        return ConstantRateMotion(rotation, np.zeros(3), t0)
    if kind == "constant_rate":
        return ConstantRateMotion(rotation, checked_array(p["body_rate_rad_s"], "body_rate_rad_s", (3,)), t0)
    if kind == "slew":
        return SlewMotion(rotation, t0=t0, **p)
    if kind == "tumble":
        return TumbleMotion(rotation, t0=t0, **p)
    base = ConstantRateMotion(rotation, checked_array(p.pop("body_rate_rad_s"), "body_rate_rad_s", (3,)), t0)
    return JitterMotion(base, **p)
