# SPDX-License-Identifier: Apache-2.0
"""
A spacecraft in orbit and its star-tracker heads: what each head's camera follows and sees.

The orbit (models.orbit: Keplerian or TLE), the body's attitude mode (sim.attitude_modes:
inertial, nadir, Sun-pointing) and each head's mounting give every head's motion (sensor ->
ICRS, the rate in the head frame); the ephemeris (models.ephemeris) gives, at a frame's stamp,
the frame's Environment (sim.environment: the spacecraft's position and velocity, the Sun, the
Moon and the planets around it, the observer's barycentric velocity for the aberration).

Time: stamps are UNIX seconds (UTC) of the orbit's own time line. A scenario that runs faster
than real time (a full orbit in minutes) runs the frames' clock faster (ROS sim time: the
demo's /clock), never the orbit faster than its frames: each exposure's smear comes from the
true body rate.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..models.attitude import rotation_vector_to_matrix
from ..models.ephemeris import PLANETS
from .attitude_modes import HeadMounting, MountedHeadMotion
from .environment import Environment
from .motion import MotionProfile


@dataclass(frozen=True)
class Misalignment:
    """
    A head's true mounting off its nominal one: a fixed offset and a thermo-elastic drift.

    The head's true head -> body rotation is M_nominal exp([delta(t)]x), delta(t) = offset_rad +
    drift_amplitude_rad sin(2 pi (t - drift_epoch_unix_s) / drift_period_s) [rad] (head frame,
    small angles): a bias and a drift with the orbit's thermal cycle.
    """

    offset_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    drift_amplitude_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    drift_period_s: float = 5700.0
    drift_epoch_unix_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("offset_rad", "drift_amplitude_rad"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (3,) or not np.all(np.isfinite(value)) or np.linalg.norm(value) > 0.1:
                raise ValueError(f"{name}={getattr(self, name)} must be 3 finite small angles (< 0.1 rad) [rad]")
        if not (np.isfinite(self.drift_period_s) and self.drift_period_s > 0):
            raise ValueError(f"drift_period_s={self.drift_period_s} must be a positive number of seconds")

    def angles(self, unix_s: float) -> np.ndarray:
        """Return delta(t) [rad], the head-frame rotation vector of the true mounting from the nominal one."""
        phase = 2.0 * np.pi * (float(unix_s) - self.drift_epoch_unix_s) / self.drift_period_s
        return np.asarray(self.offset_rad, float) + np.asarray(self.drift_amplitude_rad, float) * np.sin(phase)


@dataclass(frozen=True, eq=False)
class MisalignedHeadMotion(MotionProfile):
    """
    A head's true motion on a misaligned mounting: R_body(t) M exp([delta(t)]x).

    The drift's own rate (~1e-8 rad/s for arcseconds over an orbit) is left out of the head's rate.
    """

    nominal: MountedHeadMotion
    misalignment: Misalignment

    def rotations_at(self, times) -> np.ndarray:
        times = np.asarray(times, float).reshape(-1)
        offsets = np.array([rotation_vector_to_matrix(self.misalignment.angles(t)) for t in times])
        return self.nominal.rotations_at(times) @ offsets

    def angular_velocity_at(self, t: float) -> np.ndarray:
        return rotation_vector_to_matrix(self.misalignment.angles(t)).T @ self.nominal.angular_velocity_at(t)


@dataclass
class Spacecraft:
    """
    A spacecraft (see the module docstring).

    orbit: anything with state(unix_s) -> (r [m], v [m/s]) geocentric GCRS; body: the body's
    motion profile (body -> ICRS, in UNIX seconds); mountings: head name -> HeadMounting
    (v_body = M v_head); ephemeris: models.ephemeris.Ephemeris (or a stand-in with the same
    methods); planets: the planets drawn in the frames (their magnitudes from the ephemeris);
    misalignments: head name -> Misalignment of its true mounting (heads not listed: nominal).
    """

    orbit: object
    body: object
    mountings: dict[str, HeadMounting]
    ephemeris: object
    planets: tuple[str, ...] = PLANETS
    misalignments: dict[str, Misalignment] = field(default_factory=dict)
    _motions: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.mountings:
            raise ValueError("a spacecraft needs at least one head (mountings is empty)")
        for name, mounting in self.mountings.items():
            if not isinstance(mounting, HeadMounting):
                raise ValueError(f"head {name!r}: mounting must be a HeadMounting, got {type(mounting).__name__}")
        strays = [name for name in self.misalignments if name not in self.mountings]
        if strays:
            raise ValueError(f"misalignments of unknown heads {strays}: the heads are {list(self.mountings)}")
        unknown = [p for p in self.planets if p not in PLANETS]
        if unknown:
            raise ValueError(f"unknown planets {unknown}: choose among {list(PLANETS)}")

    def head_motion(self, head: str):
        """Return the head's true motion profile: sensor -> ICRS rotations, the rate in the head frame [rad/s]."""
        if head not in self.mountings:
            raise ValueError(f"unknown head {head!r}: the spacecraft has {list(self.mountings)}")
        if head not in self._motions:
            motion = MountedHeadMotion(self.body, self.mountings[head])
            if head in self.misalignments:
                motion = MisalignedHeadMotion(motion, self.misalignments[head])
            self._motions[head] = motion
        return self._motions[head]

    def state(self, unix_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Return the spacecraft's geocentric position [m] and velocity [m/s], GCRS, at unix_s."""
        r, v = self.orbit.state(float(unix_s))
        return np.asarray(r, float), np.asarray(v, float)

    def environment(self, unix_s: float) -> Environment:
        """Return what surrounds the spacecraft at unix_s: the frame's Environment (geocentric GCRS, SI units)."""
        r, v = self.state(unix_s)
        return environment_at(self.ephemeris, unix_s, r, v, self.planets)


def environment_at(ephemeris, unix_s: float, position_m, velocity_m_s, planets=PLANETS) -> Environment:
    """
    Return the Environment of a spacecraft at position_m [m], velocity_m_s [m/s] (geocentric GCRS) at unix_s.

    The Sun, the Moon and `planets` from the ephemeris (geocentric, astrometric), the planets'
    magnitudes, and the observer's barycentric velocity (the Earth's + velocity_m_s).
    """
    r, v = np.asarray(position_m, float), np.asarray(velocity_m_s, float)
    positions = [np.asarray(ephemeris.position(p, unix_s), float) for p in planets]
    magnitudes = [float(ephemeris.planet_magnitude(p, unix_s)) for p in planets]
    return Environment(spacecraft_position_m=r, spacecraft_velocity_m_s=v,
                       sun_position_m=np.asarray(ephemeris.sun_position(unix_s), float),
                       moon_position_m=np.asarray(ephemeris.moon_position(unix_s), float),
                       observer_velocity_m_s=np.asarray(ephemeris.earth_velocity(unix_s), float) + v,
                       planet_positions_m=np.array(positions).reshape(-1, 3), planet_magnitudes=np.array(magnitudes))
