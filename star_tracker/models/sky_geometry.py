# SPDX-License-Identifier: Apache-2.0
"""
Where the bright bodies stand relative to a star tracker head.

For a head (boresight unit vector, half field of view) and the spacecraft's geocentric
position, with the Sun's and the Moon's geocentric positions (GCRS axes, metres; no
ephemeris lookup here), this gives the angles from the boresight to the Sun, the Moon, the
Earth's centre, its limb and its nearest sunlit point, the Earth's apparent angular radius,
which directions the Earth occults, whether the Sun is eclipsed, and the head's status from
its exclusion angles. ROS-free: the identifier predicts exclusions with it and the simulator
renders them.

Model: a spherical Earth of radius earth_radius_m; the occulting sphere (the "limb") adds
atmosphere_height_m. The Sun is a point at its position: it is eclipsed when the Earth's
occulting sphere hides its centre (no penumbra). The Earth is lit where the Sun's geocentric
direction is above the local horizon of the occulting sphere (no twilight).
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..parameter_spec import parameter, range_problems

EARTH_EQUATORIAL_RADIUS_M = 6_378_137.0  # WGS-84
MOON_RADIUS_M = 1_737_400.0  # mean radius (IAU)
LIMB_SAMPLES = 1440  # points on the limb and terminator circles searched for the nearest sunlit point (~0.1 deg)


@dataclass(frozen=True)
class ExclusionModel:
    """
    A head's exclusion angles and the Earth's occulting sphere.

    Exclusion angles [rad] are measured from the boresight: to the Sun's centre, to the
    Moon's centre and to the nearest sunlit point of the Earth (disc + atmosphere).
    earth_radius_m [m]: spherical Earth; atmosphere_height_m [m]: added to it for
    occultation and for the limb.
    """

    sun_exclusion_rad: float = parameter(math.radians(30.0), "Sun exclusion angle from the boresight", "rad",
                                         0.0, math.pi)
    moon_exclusion_rad: float = parameter(math.radians(25.0), "Moon exclusion angle from the boresight", "rad",
                                          0.0, math.pi)
    earth_limb_exclusion_rad: float = parameter(math.radians(20.0), "lit Earth limb exclusion angle from the "
                                                "boresight", "rad", 0.0, math.pi)
    earth_radius_m: float = parameter(EARTH_EQUATORIAL_RADIUS_M, "radius of the spherical Earth", "m", 1.0, 1e8)
    atmosphere_height_m: float = parameter(100e3, "atmosphere added to the Earth's radius for occultation and the "
                                           "limb", "m", 0.0, 1e6)

    def __post_init__(self) -> None:
        problems = range_problems(self)
        if problems:
            raise ValueError("invalid exclusion model: " + "; ".join(problems))

    @property
    def limb_radius_m(self) -> float:
        """Radius of the occulting sphere: Earth + atmosphere [m]."""
        return self.earth_radius_m + self.atmosphere_height_m


class BodyPositions(NamedTuple):
    """
    Where the spacecraft and the bright bodies are, at one time.

    Geocentric positions [m], GCRS axes, each (3,): spacecraft_m, sun_m, moon_m.
    """

    spacecraft_m: np.ndarray
    sun_m: np.ndarray
    moon_m: np.ndarray


class HeadStatus(str, enum.Enum):
    """
    What a head can do, from the bodies' geometry, in order of precedence.

    OCCULTED: the boresight itself lies on the Earth's disc (+ atmosphere); BLINDED_SUN: the
    Sun (not eclipsed) within its exclusion angle; BLINDED_EARTH: a sunlit part of the Earth
    within the limb exclusion angle; BLINDED_MOON: the Moon (not behind the Earth) within its
    exclusion angle; TRACKING_POSSIBLE: none of these.
    """

    TRACKING_POSSIBLE = "tracking_possible"
    BLINDED_SUN = "blinded_sun"
    BLINDED_EARTH = "blinded_earth"
    BLINDED_MOON = "blinded_moon"
    OCCULTED = "occulted"


@dataclass(frozen=True)
class HeadGeometry:
    """
    The bright bodies seen from one head at one time.

    Angles [rad] from the boresight: sun_angle_rad, moon_angle_rad (centres),
    earth_centre_angle_rad, earth_limb_angle_rad (to the occulting sphere's limb; negative
    when the boresight is on the disc), lit_earth_angle_rad (to the nearest sunlit point of
    the visible occulting sphere; 0 when the boresight is on it, inf when no sunlit part is
    visible). earth_angular_radius_rad: the solid Earth's apparent radius;
    limb_angular_radius_rad: with the atmosphere; moon_angular_radius_rad. Unit vectors
    (GCRS) from the spacecraft: sun_direction, moon_direction, earth_direction (centre),
    lit_earth_direction (the nearest sunlit point; NaN when none is visible). sun_eclipsed:
    the Earth hides the Sun's centre; moon_occulted: the Earth hides the Moon's centre;
    earth_lit_fraction: the sunlit fraction of the Earth's disc as seen [-];
    earth_in_field / moon_in_field: part of the body lies within half_fov_rad of the
    boresight; status: HeadStatus.
    """

    sun_angle_rad: float
    moon_angle_rad: float
    earth_centre_angle_rad: float
    earth_limb_angle_rad: float
    lit_earth_angle_rad: float
    earth_angular_radius_rad: float
    limb_angular_radius_rad: float
    moon_angular_radius_rad: float
    sun_direction: np.ndarray
    moon_direction: np.ndarray
    earth_direction: np.ndarray
    lit_earth_direction: np.ndarray
    sun_eclipsed: bool
    moon_occulted: bool
    earth_lit_fraction: float
    earth_in_field: bool
    moon_in_field: bool
    status: HeadStatus


def unit(vectors: np.ndarray) -> np.ndarray:
    """Return the vectors (..., 3) scaled to unit length."""
    vectors = np.asarray(vectors, dtype=float)
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the angle [rad] between vectors a and b (..., 3), accurate at 0 and pi (atan2 of |a x b| and a . b)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def angular_radius(distance_m: float, radius_m: float) -> float:
    """Return the apparent angular radius [rad] of a sphere of radius_m [m] whose centre is distance_m [m] away."""
    if not distance_m > radius_m:
        raise ValueError(f"the observer ({distance_m:.0f} m from the centre) is inside the sphere of radius "
                         f"{radius_m:.0f} m")
    return math.asin(radius_m / distance_m)


def earth_occults(directions: np.ndarray, spacecraft_m: np.ndarray, radius_m: float,
                  distances_m: np.ndarray | float | None = None) -> np.ndarray:
    """
    Return which of the unit directions (N, 3) from the spacecraft the sphere of radius_m hides.

    spacecraft_m: geocentric position [m] (outside the sphere). A direction is hidden when its
    ray meets the sphere; with distances_m [m] (a body at that distance), only when it meets
    it nearer than the body (a body in front of the Earth stays visible). GCRS axes.
    """
    r = np.asarray(spacecraft_m, dtype=float)
    d = np.atleast_2d(np.asarray(directions, dtype=float))
    r2 = float(r @ r)
    if r2 <= radius_m * radius_m:
        raise ValueError("the spacecraft is inside the Earth's occulting sphere")
    along = d @ r  # r . d: negative toward the Earth
    disc = along * along - (r2 - radius_m * radius_m)
    hit = (along < 0.0) & (disc > 0.0)
    if distances_m is None:
        return hit
    near = -along - np.sqrt(np.maximum(disc, 0.0))  # distance to the first crossing of the sphere [m]
    return hit & (near < np.asarray(distances_m, dtype=float))


def _circle(centre: np.ndarray, normal: np.ndarray, radius: float, samples: int) -> np.ndarray:
    """Return `samples` points (samples, 3) of the circle of `radius` about `centre` in the plane normal to `normal`."""
    normal = unit(normal)
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    u = unit(np.cross(normal, helper))
    v = np.cross(normal, u)
    phi = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    return centre + radius * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)


def nearest_lit_earth(boresight: np.ndarray, spacecraft_m: np.ndarray, sun_m: np.ndarray,
                      radius_m: float) -> tuple[float, np.ndarray]:
    """
    Return the angle [rad] from the boresight to the nearest sunlit visible point of the sphere, and its direction.

    The sunlit visible region is bounded by the lit part of the limb circle and the visible
    part of the terminator circle; its nearest point to the boresight lies on that boundary,
    unless the boresight itself meets a sunlit point (angle 0, direction = boresight). Both
    circles are sampled at LIMB_SAMPLES points (the angle is good to ~0.1 deg from low orbit,
    better from higher). (inf, NaN vector) when no sunlit part is
    visible. Inputs: unit boresight (GCRS), geocentric positions [m].
    """
    r = np.asarray(spacecraft_m, dtype=float)
    b = unit(boresight)
    sun_hat = unit(sun_m)
    distance = float(np.linalg.norm(r))
    if earth_occults(b, r, radius_m)[0]:
        along = float(b @ r)
        near = -along - math.sqrt(along * along - (distance * distance - radius_m * radius_m))
        if (r + near * b) @ sun_hat > 0.0:
            return 0.0, b
    r_hat = r / distance
    limb = _circle(r_hat * radius_m * radius_m / distance, r_hat,
                   radius_m * math.sqrt(1.0 - (radius_m / distance) ** 2), LIMB_SAMPLES)
    terminator = _circle(np.zeros(3), sun_hat, radius_m, LIMB_SAMPLES)
    points = np.concatenate([limb[limb @ sun_hat > 0.0], terminator[terminator @ r > radius_m * radius_m]])
    if points.shape[0] == 0:
        return math.inf, np.full(3, np.nan)
    directions = unit(points - r)
    best = int(np.argmax(directions @ b))  # the smallest angle
    return float(angle_between(directions[best], b)), directions[best]


def head_geometry(boresight: np.ndarray, half_fov_rad: float, bodies: BodyPositions,
                  model: ExclusionModel = ExclusionModel()) -> HeadGeometry:
    """
    Return the bright bodies' geometry and the status of a head.

    boresight: the head's +Z axis (GCRS unit vector); half_fov_rad [rad]: the field's half
    angle (e.g. the half diagonal), for the in-field flags only; bodies: geocentric
    positions [m]; model: exclusion angles and the Earth's sphere.
    """
    b = unit(boresight)
    r = np.asarray(bodies.spacecraft_m, dtype=float)
    distance = float(np.linalg.norm(r))
    sun_vector, moon_vector = np.asarray(bodies.sun_m, float) - r, np.asarray(bodies.moon_m, float) - r
    sun_dir, moon_dir, earth_dir = unit(sun_vector), unit(moon_vector), -r / distance
    limb_radius = angular_radius(distance, model.limb_radius_m)
    moon_radius = angular_radius(float(np.linalg.norm(moon_vector)), MOON_RADIUS_M)
    centre_angle = float(angle_between(b, earth_dir))
    sun_angle, moon_angle = float(angle_between(b, sun_dir)), float(angle_between(b, moon_dir))
    sun_eclipsed = bool(earth_occults(sun_dir, r, model.limb_radius_m, np.linalg.norm(sun_vector))[0])
    moon_occulted = bool(earth_occults(moon_dir, r, model.limb_radius_m, np.linalg.norm(moon_vector))[0])
    lit_angle, lit_dir = nearest_lit_earth(b, r, bodies.sun_m, model.limb_radius_m)
    phase = float(angle_between(unit(bodies.sun_m), -earth_dir))  # Sun-Earth-spacecraft angle
    if centre_angle < limb_radius:
        status = HeadStatus.OCCULTED
    elif not sun_eclipsed and sun_angle < model.sun_exclusion_rad:
        status = HeadStatus.BLINDED_SUN
    elif lit_angle < model.earth_limb_exclusion_rad:
        status = HeadStatus.BLINDED_EARTH
    elif not moon_occulted and moon_angle < model.moon_exclusion_rad:
        status = HeadStatus.BLINDED_MOON
    else:
        status = HeadStatus.TRACKING_POSSIBLE
    return HeadGeometry(
        sun_angle_rad=sun_angle, moon_angle_rad=moon_angle, earth_centre_angle_rad=centre_angle,
        earth_limb_angle_rad=centre_angle - limb_radius, lit_earth_angle_rad=lit_angle,
        earth_angular_radius_rad=angular_radius(distance, model.earth_radius_m), limb_angular_radius_rad=limb_radius,
        moon_angular_radius_rad=moon_radius, sun_direction=sun_dir, moon_direction=moon_dir, earth_direction=earth_dir,
        lit_earth_direction=lit_dir, sun_eclipsed=sun_eclipsed, moon_occulted=moon_occulted,
        earth_lit_fraction=0.5 * (1.0 + math.cos(phase)), earth_in_field=centre_angle - limb_radius < half_fov_rad,
        moon_in_field=not moon_occulted and moon_angle - moon_radius < half_fov_rad, status=status)
