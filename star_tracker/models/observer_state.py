# SPDX-License-Identifier: Apache-2.0
"""
Where the spacecraft is and how fast it moves, over time, and what that puts around it.

`ObserverTrack` keeps the newest position and velocity samples (e.g. from a navigation
solution, nav_msgs/Odometry in GCRS) and gives the state at a frame's stamp, extrapolated from
the newest sample at or before it under the Earth's central gravity (two_body_step: over 60 s
in LEO within ~40 m and ~1.3 m/s of an orbit with J2, i.e. 0.001" of aberration, far below
what the attitude or the exclusion prediction can tell), or None when that sample is older
than max_age_s. `ObserverSky` adds the ephemeris (models.ephemeris): the bright bodies'
positions around the spacecraft for the exclusion prediction (models.sky_geometry) and the
observer's total barycentric velocity for the aberration (the Earth's + the orbital).
Positions [m] geocentric, GCRS axes; velocities [m/s]; stamps [ns] on the frames' clock (UNIX
time: the ephemeris reads it as UTC).
"""
from __future__ import annotations

from collections import deque
from typing import NamedTuple

import numpy as np

from .orbit import EARTH_MU_M3_S2
from .sky_geometry import BodyPositions


TWO_BODY_STEP_S = 10.0


class ObserverSample(NamedTuple):
    """The spacecraft's state at stamp_ns [ns]: position_m (3,) [m] geocentric GCRS, velocity_m_s (3,) [m/s]."""

    stamp_ns: int
    position_m: np.ndarray
    velocity_m_s: np.ndarray


class ObserverTrack:
    """The newest observer samples (at most `keep`), each checked: finite, geocentric metres, newer than the last."""

    def __init__(self, max_age_s: float, keep: int = 32):
        if not (np.isfinite(max_age_s) and max_age_s > 0):
            raise ValueError(f"max_age_s={max_age_s} must be a positive number of seconds")
        self.max_age_ns = int(max_age_s * 1e9)
        self.samples: deque[ObserverSample] = deque(maxlen=keep)

    def add(self, stamp_ns: int, position_m, velocity_m_s) -> None:
        """Append a sample; ValueError (naming what is wrong) for a bad or out-of-order one."""
        position = np.asarray(position_m, dtype=float)
        velocity = np.asarray(velocity_m_s, dtype=float)
        if position.shape != (3,) or velocity.shape != (3,):
            raise ValueError(f"position and velocity must be 3 values each, got {position.shape} and {velocity.shape}")
        if not (np.all(np.isfinite(position)) and np.all(np.isfinite(velocity))):
            raise ValueError("position and velocity must be finite")
        if np.linalg.norm(position) < 1.0e6:
            raise ValueError(f"position {position.tolist()} m is {np.linalg.norm(position) / 1e3:.0f} km from the "
                             "Earth's centre: not a geocentric position in metres")
        if np.linalg.norm(velocity) > 3.0e5:
            raise ValueError(f"velocity {velocity.tolist()} m/s is faster than any spacecraft: not in m/s")
        if self.samples and stamp_ns <= self.samples[-1].stamp_ns:
            raise ValueError(f"sample at {stamp_ns * 1e-9:.6f} s is not newer than the last one "
                             f"({self.samples[-1].stamp_ns * 1e-9:.6f} s)")
        self.samples.append(ObserverSample(int(stamp_ns), position, velocity))

    def at(self, stamp_ns: int) -> ObserverSample | None:
        """Return the state at stamp_ns from the newest sample at or before it within max_age_s (else the next one)."""
        before = [s for s in self.samples if s.stamp_ns <= stamp_ns]
        sample = before[-1] if before else next(iter(self.samples), None)
        if sample is None or abs(stamp_ns - sample.stamp_ns) > self.max_age_ns:
            return None
        position, velocity = two_body_step(sample.position_m, sample.velocity_m_s, (stamp_ns - sample.stamp_ns) * 1e-9)
        return ObserverSample(int(stamp_ns), position, velocity)


def two_body_step(position_m: np.ndarray, velocity_m_s: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Return the geocentric state dt_s [s] later under the Earth's central gravity (RK4, steps of at most 10 s)."""
    def derivative(r, v):
        return v, -EARTH_MU_M3_S2 * r / np.linalg.norm(r) ** 3

    steps = max(1, int(np.ceil(abs(dt_s) / TWO_BODY_STEP_S)))
    h = dt_s / steps
    r, v = np.asarray(position_m, float), np.asarray(velocity_m_s, float)
    for _ in range(steps):
        k1r, k1v = derivative(r, v)
        k2r, k2v = derivative(r + 0.5 * h * k1r, v + 0.5 * h * k1v)
        k3r, k3v = derivative(r + 0.5 * h * k2r, v + 0.5 * h * k2v)
        k4r, k4v = derivative(r + h * k3r, v + h * k3v)
        r = r + h / 6.0 * (k1r + 2 * k2r + 2 * k3r + k4r)
        v = v + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return r, v


class ObserverSky:
    """
    The bright bodies around an observer and its barycentric velocity, from an ephemeris.

    ephemeris: anything with sun_position(unix_s), moon_position(unix_s) (geocentric [m]) and
    earth_velocity(unix_s) [m/s] (models.ephemeris.Ephemeris).
    """

    def __init__(self, ephemeris):
        self.ephemeris = ephemeris

    def bodies(self, state: ObserverSample) -> BodyPositions:
        """Return the spacecraft, the Sun and the Moon (geocentric, GCRS [m]) at the state's stamp."""
        unix_s = state.stamp_ns * 1e-9
        return BodyPositions(state.position_m, np.asarray(self.ephemeris.sun_position(unix_s), float),
                             np.asarray(self.ephemeris.moon_position(unix_s), float))

    def barycentric_velocity(self, state: ObserverSample) -> np.ndarray:
        """Return the observer's velocity relative to the solar-system barycentre [m/s] (ICRS axes)."""
        return np.asarray(self.ephemeris.earth_velocity(state.stamp_ns * 1e-9), float) + state.velocity_m_s
