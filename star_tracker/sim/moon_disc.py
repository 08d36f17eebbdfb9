# SPDX-License-Identifier: Apache-2.0
"""
The Moon in the field: an extended disc of its apparent size and phase, as sky-fixed sample points.

The disc (angular radius asin(R_moon / d), d: spacecraft-Moon distance) is sampled on a
square grid in the tangent plane about the Moon's centre, one sample per 1.5 min(1, sigma_PSF)
px (the PSF smooths the grid's ripple to exp(-2 pi^2 / 1.5^2) ~ 1e-4); a sample is lit when
the Moon's surface normal under it faces the Sun (the terminator follows the Sun's direction
from the Moon); the lit samples share the Moon's electrons equally (a uniformly bright lit
surface). The renderer smears and integrates them like stars. Samples the Earth's occulting
sphere hides are dropped with their share.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..models.camera import CameraModel
from ..models.sky_geometry import HeadGeometry, earth_occults, unit
from .apparent_directions import apparent_directions
from .body_brightness import MOON_B_V, moon_magnitude
from .environment import Environment, EnvironmentModel
from .sensor import SensorModel
from .stray_light import moon_lit_fraction

SAMPLE_SPACING_SIGMA = 1.5  # disc samples' spacing in PSF sigmas (at most 1.5 px)


class MoonDisc(NamedTuple):
    """
    The Moon's disc in one frame.

    vectors (N, 3): apparent GCRS unit directions of its lit, unhidden samples; electrons
    (N,): each one's expected electrons per exposure [e-]; centre: apparent direction of its
    centre (3,); radius_rad [rad] and radius_px [px] (local plate scale): apparent radius;
    total_e: the sum of electrons [e-].
    """

    vectors: np.ndarray
    electrons: np.ndarray
    centre: np.ndarray
    radius_rad: float
    radius_px: float
    total_e: float


class DiscView(NamedTuple):
    """What moon_disc needs to know of the frame: camera, sensor, attitude rot_mid (sensor -> GCRS), the model."""

    camera: CameraModel
    sensor: SensorModel
    rot_mid: np.ndarray
    model: EnvironmentModel


def moon_disc(view: DiscView, head: HeadGeometry, environment: Environment) -> MoonDisc | None:
    """
    Return the Moon's disc when some of it may reach the chip (None otherwise, or when it is behind the Earth).

    head: the bodies' geometry at mid-exposure; environment: positions [m], velocity for
    aberration [m/s] and the Moon's phase.
    """
    camera, sensor, rot_mid = view.camera, view.sensor, view.rot_mid
    radius = head.moon_angular_radius_rad
    reach = camera.half_diagonal_fov_rad + radius + 0.02  # 0.02 rad: PSF wings and smear
    if head.moon_occulted or head.moon_angle_rad > reach:
        return None
    centre = head.moon_direction
    east = unit(rot_mid[:, 0] - (rot_mid[:, 0] @ centre) * centre)  # image +X in the tangent plane
    south = np.cross(centre, east)  # image +Y
    step = SAMPLE_SPACING_SIGMA * min(1.0, sensor.psf_sigma_px) * camera.pixel_scale_rad
    n = int(math.ceil(radius / step))
    xi, eta = np.meshgrid(np.arange(-n, n + 1) * step, np.arange(-n, n + 1) * step)
    inside = xi * xi + eta * eta <= radius * radius
    x, y = xi[inside] / radius, eta[inside] / radius
    normals = (x[:, None] * east + y[:, None] * south
               - np.sqrt(np.maximum(1.0 - x * x - y * y, 0.0))[:, None] * centre)
    lit = normals @ unit(environment.sun_position_m - environment.moon_position_m) > 0.0
    directions = unit(centre + xi[inside][:, None] * east + eta[inside][:, None] * south)
    distance = float(np.linalg.norm(environment.moon_position_m - environment.spacecraft_position_m))
    shown = lit
    if view.model.earth_occultation:
        shown = lit & ~earth_occults(directions, environment.spacecraft_position_m,
                                     view.model.exclusion.limb_radius_m, distance)
    total = float(sensor.star_electrons(moon_magnitude(moon_lit_fraction(environment), distance), MOON_B_V))
    per_sample = total / max(int(np.count_nonzero(lit)), 1)
    vectors, centre_seen = directions[shown], centre[None, :]
    if view.model.aberration:
        vectors = apparent_directions(vectors, environment.observer_velocity_m_s)
        centre_seen = apparent_directions(centre_seen, environment.observer_velocity_m_s)
    electrons = np.full(vectors.shape[0], per_sample)
    return MoonDisc(vectors, electrons, centre_seen[0], radius, radius / camera.pixel_scale_rad,
                    float(electrons.sum()))
