# SPDX-License-Identifier: Apache-2.0
"""
How bright the Sun, the Moon and the lit Earth are at the spacecraft, as visual magnitudes.

The renderer turns a magnitude into photo-electrons with the sensor's radiometry
(SensorModel.star_electrons), so a body's irradiance is written as the magnitude of a star
that would give the same: the Sun V = -26.74 (the solar constant); the Moon by Allen's phase
law at its distance; the lit Earth as the Sun times its albedo, the solid angle of its disc
and its sunlit fraction.
"""
from __future__ import annotations

import math

SUN_V_MAGNITUDE = -26.74  # apparent V magnitude of the Sun at 1 au (solar constant ~1361 W/m^2)
SUN_B_V = 0.65
MOON_B_V = 0.92
EARTH_B_V = SUN_B_V  # reflected sunlight
MOON_MEAN_DISTANCE_M = 384_400e3  # Allen's magnitudes are at the mean distance


def phase_angle_from_fraction(illuminated_fraction: float) -> float:
    """Return the phase angle [rad] (Sun-body-observer) of a sphere whose disc is `illuminated_fraction` lit."""
    if not 0.0 <= illuminated_fraction <= 1.0:
        raise ValueError(f"illuminated fraction {illuminated_fraction} must be in [0, 1]")
    return math.acos(2.0 * illuminated_fraction - 1.0)


def moon_magnitude(illuminated_fraction: float, distance_m: float) -> float:
    """
    Return the Moon's V magnitude seen from distance_m [m] when its disc is illuminated_fraction lit.

    Allen: V = -12.73 + 0.026 |a| + 4e-9 a^4 (a: phase angle in degrees) at the mean
    distance, + 5 log10(distance / mean distance). inf for a new Moon (fraction 0).
    """
    if illuminated_fraction <= 0.0:
        return math.inf
    alpha_deg = math.degrees(phase_angle_from_fraction(illuminated_fraction))
    return -12.73 + 0.026 * alpha_deg + 4e-9 * alpha_deg ** 4 + 5.0 * math.log10(distance_m / MOON_MEAN_DISTANCE_M)


def earth_magnitude(albedo: float, angular_radius_rad: float, lit_fraction: float) -> float:
    """
    Return the lit Earth's V magnitude at the spacecraft: the Sun's less 2.5 log10(albedo sin^2(rho) k).

    A Lambertian disc of albedo A [-] under the solar irradiance S gives A S sin^2(rho) at a
    spacecraft that sees it with angular radius rho [rad]; k [-] is the disc's sunlit
    fraction. inf when nothing of it is lit.
    """
    ratio = albedo * math.sin(angular_radius_rad) ** 2 * lit_fraction
    return SUN_V_MAGNITUDE - 2.5 * math.log10(ratio) if ratio > 0.0 else math.inf
