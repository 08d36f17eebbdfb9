# SPDX-License-Identifier: Apache-2.0
"""
Spacecraft attitude modes and star-tracker head mountings, as motion profiles.

A body mode is a MotionProfile (sim/motion.py) of the body frame: rotations_at(times) -> (K, 3, 3)
body -> ICRS (v_icrs = R v_body) and angular_velocity_at(t) -> (3,) the body rate in the body
frame [rad/s]. Times are UNIX seconds (UTC), the clock of the orbit's state(times).

- inertial_attitude: a fixed attitude.
- NadirPointingMotion (LVLH): body +Z to nadir (-r / |r|, the Earth's centre), +Y along the negative
  orbit normal (-(r x v) / |r x v|), +X = Y x Z (along the velocity's component across r: exactly
  along v on a circular orbit). It turns at the orbital rate about -Y (|r x v| / |r|^2) plus a
  roll about Z when the orbit plane turns (J2, SGP4).
- SunPointingMotion: a body axis (default +Z) at the Sun seen from the spacecraft (astrometric:
  no aberration, 20 arcsec from the apparent Sun), a second body axis (default +X) as close as it
  can be to an ICRS reference direction (default the ecliptic north pole, always ~90 deg from the
  Sun, so the roll is never undefined).

Modes are built on an orbit (anything with state(times) -> (r [m], v [m/s]) GCRS, e.g.
models/orbit.py) and, for Sun pointing, anything with sun_position(times) -> geocentric GCRS [m]
(e.g. models/ephemeris.py's Ephemeris, or a stand-in). Rates are analytic in r, v and the Sun's
vector; the two quantities the interfaces do not give, the orbit's acceleration (only its component
across the orbit plane counts, for the roll) and the Sun's geocentric velocity, come from 5-point
central differences (truncation < 1e-15 rad/s).

A head: HeadMounting holds the head -> body rotation M (v_body = M v_head: the columns are the head's
+X right, +Y down, +Z boresight in body axes; ROS tf's transform from parent "body" to child "head").
MountedHeadMotion gives the head's sensor -> ICRS rotation R_body M and its rate M^T omega_body.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..models.attitude import matrix_to_quaternion, quaternion_to_matrix
from .motion import ConstantRateMotion, MotionProfile, as_times, checked_array, checked_rotation

# Ecliptic north pole in ICRS: the J2000 obliquity (IAU 2006, 84381.406 arcsec) about +X.
_OBLIQUITY_RAD = np.radians(84381.406 / 3600.0)
ECLIPTIC_NORTH_ICRS = np.array([0.0, -np.sin(_OBLIQUITY_RAD), np.cos(_OBLIQUITY_RAD)])
_ORBIT_STEP_S = 1.0  # finite-difference step of the orbit's acceleration
_SUN_STEP_S = 60.0  # and of the Sun's geocentric velocity
_STENCIL = np.array([1.0, -8.0, 0.0, 8.0, -1.0]) / 12.0  # d/dt at the middle of f(t-2h) .. f(t+2h), / h


def inertial_attitude(rotation) -> MotionProfile:
    """Return a fixed attitude: rotation (3, 3) body -> ICRS at every time, zero rate."""
    return ConstantRateMotion(checked_rotation(rotation, "rotation"), np.zeros(3))


def _time(t) -> float:
    times = as_times(t)
    if times.size != 1:
        raise ValueError(f"t must be one time [s], got {t!r}")
    return float(times[0])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _check_orbit(orbit) -> None:
    if not callable(getattr(orbit, "state", None)):
        raise ValueError(f"orbit must have state(times) -> (r, v), got {orbit!r}")


def _derivative(function, t: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Value (3,) and 5-point central derivative (3,) of a vectorized function of time at t."""
    values = np.asarray(function(t + step * np.arange(-2.0, 3.0)), dtype=float)
    return values[2], np.tensordot(_STENCIL, values, axes=1) / step


def _triad_rate(axes: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Angular velocity (3,) of an orthonormal triad (columns of axes) from the columns' time derivatives."""
    t1, t2, t3 = axes.T
    d1, d2, d3 = rates.T
    return t1 * (d2 @ t3) + t2 * (d3 @ t1) + t3 * (d1 @ t2)


@dataclass(frozen=True, eq=False)
class NadirPointingMotion(MotionProfile):
    """Nadir pointing in the LVLH frame of an orbit (axes: see the module docstring)."""

    orbit: object

    def __post_init__(self) -> None:
        _check_orbit(self.orbit)

    @staticmethod
    def _axes(r: np.ndarray, v: np.ndarray) -> np.ndarray:
        z = -_unit(r)
        y = -_unit(np.cross(r, v))
        return np.stack([np.cross(y, z), y, z], axis=-1)

    def rotations_at(self, times) -> np.ndarray:
        r, v = (np.asarray(x, dtype=float).reshape(-1, 3) for x in self.orbit.state(as_times(times)))
        return self._axes(r, v)

    def angular_velocity_at(self, t: float) -> np.ndarray:
        """
        Body rate [rad/s], exact for the frame rotations_at builds from the orbit's r and v.

        With e_r = r / |r|, h = r x v, e_h = h / |h|, e_t = e_h x e_r and the time derivatives of r
        and v: (-(dr/dt . e_h) / |r|, -(dr/dt . e_t) / |r|, (dh/dt . e_t) / |h|), dh/dt = dr/dt x v +
        r x dv/dt. When v = dr/dt it is (0, -|h| / |r|^2, -|r| (a . e_h) / |h|): the orbital rate
        about -Y and a roll as the orbit plane turns. dr/dt too comes from differences, since an
        orbit's v need not be exactly its position's derivative (SGP4's is off by ~1e-6).
        """
        t = _time(t)
        r, r_dot = _derivative(lambda s: self.orbit.state(s)[0], t, _ORBIT_STEP_S)
        v, v_dot = _derivative(lambda s: self.orbit.state(s)[1], t, _ORBIT_STEP_S)
        radius, h = np.linalg.norm(r), np.cross(r, v)
        e_h = h / np.linalg.norm(h)
        e_t = np.cross(e_h, r / radius)
        h_dot = np.cross(r_dot, v) + np.cross(r, v_dot)
        return np.array([-(r_dot @ e_h) / radius, -(r_dot @ e_t) / radius, (h_dot @ e_t) / np.linalg.norm(h)])


@dataclass(frozen=True, eq=False)
class SunPointingMotion(MotionProfile):
    """
    A body axis at the Sun, the roll set by a reference direction (see the module docstring).

    orbit: state(times) -> (r, v) GCRS [m, m/s]; ephemeris: sun_position(times) -> geocentric GCRS
    [m]; sun_axis: (3,) body axis put on the Sun (default +Z); reference_axis: (3,) body axis, not
    along sun_axis, whose component across sun_axis goes as close as it can to reference_icrs (3,)
    (default the ecliptic north pole). Raises ValueError when evaluated with the Sun along
    reference_icrs (< 1e-6 rad).
    """

    orbit: object
    ephemeris: object
    sun_axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    reference_axis: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    reference_icrs: np.ndarray = field(default_factory=lambda: ECLIPTIC_NORTH_ICRS.copy())

    def __post_init__(self) -> None:
        _check_orbit(self.orbit)
        if not callable(getattr(self.ephemeris, "sun_position", None)):
            raise ValueError(f"ephemeris must have sun_position(times) -> GCRS [m], got {self.ephemeris!r}")
        a, b, n = (checked_array(getattr(self, name), name, (3,))
                   for name in ("sun_axis", "reference_axis", "reference_icrs"))
        for name, value in (("sun_axis", a), ("reference_axis", b), ("reference_icrs", n)):
            if np.linalg.norm(value) == 0:
                raise ValueError(f"{name} must be a non-zero vector")
        a = a / np.linalg.norm(a)
        b = b - (b @ a) * a
        if np.linalg.norm(b) < 1e-6 * np.linalg.norm(getattr(self, "reference_axis")):
            raise ValueError("reference_axis must not be along sun_axis")
        b = b / np.linalg.norm(b)
        object.__setattr__(self, "reference_icrs", n / np.linalg.norm(n))
        object.__setattr__(self, "_body_triad", np.stack([a, b, np.cross(a, b)], axis=1))

    def _geocentric_sun(self, times) -> np.ndarray:
        return np.asarray(self.ephemeris.sun_position(times), dtype=float).reshape(-1, 3)

    def _sun_vector(self, times) -> np.ndarray:
        """Spacecraft -> Sun vectors (K, 3) [m]."""
        r = np.asarray(self.orbit.state(times)[0], dtype=float).reshape(-1, 3)
        return self._geocentric_sun(times) - r

    def _target(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sun direction s, the reference across it m, and the reference's part across s (unnormalized)."""
        s = _unit(d)
        p = self.reference_icrs - (s @ self.reference_icrs)[..., None] * s
        norm = np.linalg.norm(p, axis=-1, keepdims=True)
        if np.any(norm < 1e-6):
            raise ValueError("reference_icrs is along the Sun direction: the roll about it is undefined")
        return s, p / norm, norm

    def rotations_at(self, times) -> np.ndarray:
        s, m, _ = self._target(self._sun_vector(as_times(times)))
        return np.stack([s, m, np.cross(s, m)], axis=-1) @ self._body_triad.T

    def angular_velocity_at(self, t: float) -> np.ndarray:
        t = _time(t)
        r, v = (np.asarray(x, dtype=float).reshape(3) for x in self.orbit.state(t))
        sun, sun_velocity = _derivative(self._geocentric_sun, t, _SUN_STEP_S)
        d, d_dot = sun - r, sun_velocity - v
        s, m, p_norm = self._target(d)
        s_dot = (d_dot - (s @ d_dot) * s) / np.linalg.norm(d)
        n = self.reference_icrs
        p_dot = -(n @ s_dot) * s - (n @ s) * s_dot
        m_dot = (p_dot - (m @ p_dot) * m) / p_norm[0]
        axes = np.stack([s, m, np.cross(s, m)], axis=1)
        rates = np.stack([s_dot, m_dot, np.cross(s_dot, m) + np.cross(s, m_dot)], axis=1)
        return (axes @ self._body_triad.T).T @ _triad_rate(axes, rates)


@dataclass(frozen=True)
class HeadMounting:
    """
    A star-tracker head's orientation on the body: head_to_body (3, 3), v_body = M v_head.

    Columns: the head's +X (right), +Y (down), +Z (boresight) in body axes. Validated: orthonormal
    to 1e-6 and det +1 (a reflection is refused). from_quaternion takes the same rotation as a unit
    (x, y, z, w) quaternion (norm within 1e-6 of 1); quaternion returns it.
    """

    head_to_body: np.ndarray

    def __post_init__(self) -> None:
        m = checked_array(self.head_to_body, "head_to_body", (3, 3))
        if not np.allclose(m.T @ m, np.eye(3), atol=1e-6):
            raise ValueError("head_to_body must be orthonormal (a rotation matrix)")
        if np.linalg.det(m) < 0:
            raise ValueError("head_to_body must be a proper rotation (det +1), got a reflection (det -1)")
        object.__setattr__(self, "head_to_body", m)

    @classmethod
    def from_quaternion(cls, q_xyzw) -> "HeadMounting":
        """Mounting from the head -> body rotation as a unit quaternion (x, y, z, w)."""
        q = checked_array(q_xyzw, "q_xyzw", (4,))
        if abs(np.linalg.norm(q) - 1.0) > 1e-6:
            raise ValueError(f"q_xyzw must be a unit quaternion (x, y, z, w), got norm {np.linalg.norm(q)}")
        return cls(quaternion_to_matrix(q))

    @property
    def quaternion(self) -> np.ndarray:
        """Head -> body rotation as an (x, y, z, w) quaternion, w >= 0."""
        return matrix_to_quaternion(self.head_to_body)


@dataclass(frozen=True, eq=False)
class MountedHeadMotion(MotionProfile):
    """A head's motion: sensor -> ICRS rotations R_body M and the rate M^T omega_body in the head frame [rad/s]."""

    body: MotionProfile
    mounting: HeadMounting

    def __post_init__(self) -> None:
        if not all(callable(getattr(self.body, m, None)) for m in ("rotations_at", "angular_velocity_at")):
            raise ValueError(f"body must be a motion profile (rotations_at, angular_velocity_at), got {self.body!r}")
        if not isinstance(self.mounting, HeadMounting):
            raise ValueError(f"mounting must be a HeadMounting, got {type(self.mounting).__name__}")

    def rotations_at(self, times) -> np.ndarray:
        return np.asarray(self.body.rotations_at(as_times(times))) @ self.mounting.head_to_body

    def angular_velocity_at(self, t: float) -> np.ndarray:
        return self.mounting.head_to_body.T @ np.asarray(self.body.angular_velocity_at(t), dtype=float)
