# SPDX-License-Identifier: Apache-2.0
"""
Stray light from the Sun, the lit Earth and the Moon: a background plane over the frame.

A point-source-transmittance (PST) law of the source's angle from the boresight, scaled by
the source's irradiance (its magnitude), gives each source's level at the image centre; the
level tilts linearly across the image toward the source. Inside a source's exclusion angle
the baffle is lit directly and the PST jumps to pst_inside_exclusion: with the Sun or the lit
Earth that floods every pixel far past the full well (a blinded frame). Parameters:
sim.environment.EnvironmentModel.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..models.camera import CameraModel
from ..models.sky_geometry import HeadGeometry
from .body_brightness import EARTH_B_V, MOON_B_V, SUN_B_V, SUN_V_MAGNITUDE, earth_magnitude, moon_magnitude
from .environment import Environment, EnvironmentModel
from .sensor import SensorModel


class StraySource(NamedTuple):
    """
    One stray-light source as the head sees it.

    angle_rad: from the boresight [rad]; exclusion_rad: its exclusion angle [rad];
    direction: unit vector from the spacecraft (GCRS); magnitude, b_v: its irradiance as a
    star's V magnitude and colour.
    """

    angle_rad: float
    exclusion_rad: float
    direction: np.ndarray
    magnitude: float
    b_v: float


class StrayPlane(NamedTuple):
    """
    Stray light over the image: level_e + gradient_x_e x' + gradient_y_e y' [e- per pixel per exposure].

    x', y': pixel offsets from the principal point over the half diagonal [-]; levels_e:
    each source's level at the centre (Sun, Earth, Moon) [e-].
    """

    level_e: float
    gradient_x_e: float
    gradient_y_e: float
    levels_e: tuple[float, float, float]

    def swing_e(self, camera: CameraModel) -> float:
        """Return the largest departure of the plane from its centre level over the image [e-]."""
        x, y = normalized_extent(camera)
        return max(abs(self.gradient_x_e * x[0]), abs(self.gradient_x_e * x[1])) + max(
            abs(self.gradient_y_e * y[0]), abs(self.gradient_y_e * y[1]))


def half_diagonal_px(camera: CameraModel) -> float:
    """Return the image's half diagonal [px], the unit of the stray-light gradient."""
    return math.hypot(camera.width / 2.0, camera.height / 2.0)


def normalized_extent(camera: CameraModel) -> tuple[tuple[float, float], tuple[float, float]]:
    """Return the (first, last) pixel offsets from the principal point over the half diagonal, in x and in y [-]."""
    scale = half_diagonal_px(camera)
    return ((-camera.cx / scale, (camera.width - 1 - camera.cx) / scale),
            (-camera.cy / scale, (camera.height - 1 - camera.cy) / scale))


def point_source_transmittance(angle_rad: float, exclusion_rad: float, model: EnvironmentModel) -> float:
    """
    Return the baffle's PST [-] for a source angle_rad [rad] from the boresight with exclusion angle exclusion_rad.

    pst_inside_exclusion inside the exclusion angle; pst_at_exclusion (angle /
    exclusion)^(-pst_exponent) from it to 90 deg; 0 at and beyond 90 deg.
    """
    if angle_rad >= 0.5 * math.pi:
        return 0.0
    if angle_rad < exclusion_rad:
        return model.pst_inside_exclusion
    return model.pst_at_exclusion * (angle_rad / exclusion_rad) ** (-model.pst_exponent)


def stray_sources(head: HeadGeometry, environment: Environment,
                  model: EnvironmentModel) -> tuple[StraySource | None, StraySource | None, StraySource | None]:
    """
    Return the Sun, the lit Earth and the Moon as stray-light sources (None where one gives no light).

    The Sun unless eclipsed; the Earth through its nearest sunlit visible point, with the
    albedo-weighted irradiance of its lit disc; the Moon unless behind the Earth, by its
    phase (Environment.moon_illuminated_fraction, else the Sun-Moon-spacecraft angle).
    """
    exclusion = model.exclusion
    sun = None if head.sun_eclipsed else StraySource(head.sun_angle_rad, exclusion.sun_exclusion_rad,
                                                     head.sun_direction, SUN_V_MAGNITUDE, SUN_B_V)
    earth = None
    if math.isfinite(head.lit_earth_angle_rad):
        magnitude = earth_magnitude(model.earth_albedo, head.earth_angular_radius_rad, head.earth_lit_fraction)
        earth = StraySource(head.lit_earth_angle_rad, exclusion.earth_limb_exclusion_rad, head.lit_earth_direction,
                            magnitude, EARTH_B_V)
    moon = None
    if not head.moon_occulted:
        fraction = moon_lit_fraction(environment)
        distance = float(np.linalg.norm(environment.moon_position_m - environment.spacecraft_position_m))
        moon = StraySource(head.moon_angle_rad, exclusion.moon_exclusion_rad, head.moon_direction,
                           moon_magnitude(fraction, distance), MOON_B_V)
    return sun, earth, moon


def moon_lit_fraction(environment: Environment) -> float:
    """Return the Moon's illuminated fraction [-]: the Environment's, else (1 + cos phase angle) / 2."""
    if environment.moon_illuminated_fraction is not None:
        return float(environment.moon_illuminated_fraction)
    to_sun = environment.sun_position_m - environment.moon_position_m
    to_observer = environment.spacecraft_position_m - environment.moon_position_m
    cos_phase = to_sun @ to_observer / (np.linalg.norm(to_sun) * np.linalg.norm(to_observer))
    return 0.5 * (1.0 + float(cos_phase))


def stray_plane(sources, rot_mid: np.ndarray, sensor: SensorModel, model: EnvironmentModel) -> StrayPlane:
    """
    Return the stray-light plane of the sources (StraySource or None each) for attitude rot_mid (sensor -> GCRS).

    Each source's centre level N_src PST A_pix / A_ap [e- per pixel per exposure] (0 when
    below stray_light_floor_e at every pixel); its gradient points along the source
    direction's projection on the image plane.
    """
    pixel_over_aperture = sensor.pixel_pitch_m ** 2 / (math.pi * (0.5 * sensor.aperture_diameter_m) ** 2)
    level = gx = gy = 0.0
    levels = []
    for source in sources:
        if source is None or not math.isfinite(source.magnitude):
            levels.append(0.0)
            continue
        pst = point_source_transmittance(source.angle_rad, source.exclusion_rad, model)
        value = float(sensor.star_electrons(source.magnitude, source.b_v)) * pst * pixel_over_aperture
        if value * (1.0 + model.stray_light_gradient) < model.stray_light_floor_e:
            value = 0.0  # below the floor at every pixel: left out
        levels.append(value)
        in_sensor = rot_mid.T @ source.direction
        across = math.hypot(in_sensor[0], in_sensor[1])
        level += value
        if across > 0.0:
            gx += value * model.stray_light_gradient * in_sensor[0] / across
            gy += value * model.stray_light_gradient * in_sensor[1] / across
    return StrayPlane(level, gx, gy, tuple(levels))
