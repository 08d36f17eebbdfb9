# SPDX-License-Identifier: Apache-2.0
"""
models.sky_geometry against independent computations.

Angles against astropy SkyCoord separations; the Earth's angular radius and occultation
against closed-form geometry (asin(R / r)); the nearest sunlit point of the Earth against a
brute-force search over points of the sphere; each status where its angle puts it.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import CartesianRepresentation, SkyCoord

from star_tracker.models.sky_geometry import (MOON_RADIUS_M, BodyPositions, ExclusionModel, HeadStatus,
                                              angular_radius, earth_occults, head_geometry, nearest_lit_earth)

AU_M = 1.495978707e11
MOON_DISTANCE_M = 3.844e8
MODEL = ExclusionModel()
LIMB_M = MODEL.earth_radius_m + MODEL.atmosphere_height_m


def sky(vectors) -> SkyCoord:
    x, y, z = np.asarray(vectors, dtype=float).reshape(-1, 3).T
    return SkyCoord(CartesianRepresentation(x, y, z, unit=u.m), frame="icrs")


def separation_rad(a, b) -> np.ndarray:
    return sky(a).separation(sky(b)).to_value(u.rad)


def rotate_toward(a: np.ndarray, b: np.ndarray, angle: float) -> np.ndarray:
    """Return the unit vector `angle` [rad] from unit `a` in the plane of a and b, toward b."""
    t = b - (b @ a) * a
    return math.cos(angle) * a + math.sin(angle) * t / np.linalg.norm(t)


def random_unit(rng, n=None) -> np.ndarray:
    v = rng.standard_normal((n or 1, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v if n else v[0]


def test_angles_match_astropy_separations():
    rng = np.random.default_rng(1)
    for _ in range(20):
        spacecraft = random_unit(rng) * rng.uniform(6.6e6, 4.3e7)
        bodies = BodyPositions(spacecraft, random_unit(rng) * AU_M, random_unit(rng) * MOON_DISTANCE_M)
        boresight = random_unit(rng)
        g = head_geometry(boresight, math.radians(10.0), bodies, MODEL)
        assert g.sun_angle_rad == pytest.approx(separation_rad(boresight, bodies.sun_m - spacecraft)[0], abs=1e-9)
        assert g.moon_angle_rad == pytest.approx(separation_rad(boresight, bodies.moon_m - spacecraft)[0], abs=1e-9)
        centre = separation_rad(boresight, -spacecraft)[0]
        rho = math.asin(LIMB_M / np.linalg.norm(spacecraft))
        assert g.earth_centre_angle_rad == pytest.approx(centre, abs=1e-9)
        assert g.earth_limb_angle_rad == pytest.approx(centre - rho, abs=1e-9)
        assert g.moon_angular_radius_rad == pytest.approx(
            math.asin(MOON_RADIUS_M / np.linalg.norm(bodies.moon_m - spacecraft)), rel=1e-12)


@pytest.mark.parametrize("altitude_m", [400e3, 800e3, 35_786e3])
def test_earth_angular_radius_is_closed_form(altitude_m):
    r = MODEL.earth_radius_m + altitude_m
    bodies = BodyPositions(np.array([0.0, 0.0, r]), np.array([AU_M, 0.0, 0.0]), np.array([0.0, MOON_DISTANCE_M, 0]))
    g = head_geometry(np.array([1.0, 0.0, 0.0]), 0.1, bodies, MODEL)
    # The tangent from the spacecraft to the sphere: sin(rho) = R / r.
    assert g.earth_angular_radius_rad == pytest.approx(math.atan2(MODEL.earth_radius_m,
                                                                  math.sqrt(r * r - MODEL.earth_radius_m ** 2)))
    assert g.limb_angular_radius_rad == pytest.approx(math.atan2(LIMB_M, math.sqrt(r * r - LIMB_M ** 2)))
    if altitude_m == 400e3:
        assert math.degrees(g.earth_angular_radius_rad) == pytest.approx(70.2, abs=0.05)


def test_occulted_directions_are_those_within_the_disc():
    rng = np.random.default_rng(2)
    spacecraft = np.array([7.0e6, -1.0e6, 2.0e6])
    directions = random_unit(rng, 20000)
    hidden = earth_occults(directions, spacecraft, LIMB_M)
    within = separation_rad(directions, np.tile(-spacecraft, (directions.shape[0], 1))) < \
        math.asin(LIMB_M / np.linalg.norm(spacecraft))
    assert hidden.sum() > 2000 and np.array_equal(hidden, within)


def test_a_body_in_front_of_the_earth_is_not_occulted():
    spacecraft = np.array([4.2e7, 0.0, 0.0])  # GEO, the Earth toward -x
    toward_earth = np.array([[-1.0, 0.0, 0.0]])
    # The sphere's near side is 4.2e7 - 6.478e6 = 3.55e7 m away.
    assert earth_occults(toward_earth, spacecraft, LIMB_M, 4.0e7)[0]  # beyond the near side
    assert not earth_occults(toward_earth, spacecraft, LIMB_M, 3.0e7)[0]  # in front of the Earth


def test_sun_is_eclipsed_in_the_shadow_only():
    r = MODEL.earth_radius_m + 500e3
    sun = np.array([AU_M, 0.0, 0.0])
    boresight = np.array([0.0, 0.0, 1.0])
    behind = head_geometry(boresight, 0.1, BodyPositions(np.array([-r, 0.0, 0.0]), sun, np.zeros(3) + 4e8), MODEL)
    beside = head_geometry(boresight, 0.1, BodyPositions(np.array([0.0, r, 0.0]), sun, np.zeros(3) + 4e8), MODEL)
    assert behind.sun_eclipsed and not beside.sun_eclipsed
    # The closed form: the Sun's direction within the occulting disc's angular radius.
    for g in (behind, beside):
        assert g.sun_eclipsed == (separation_rad(g.sun_direction, g.earth_direction)[0] < g.limb_angular_radius_rad)


def fibonacci_cap(points: int, half_angle_rad: float = math.pi) -> np.ndarray:
    """Return `points` unit vectors spread evenly over the cap within half_angle_rad of +z."""
    i = np.arange(points) + 0.5
    z = 1.0 - (1.0 - math.cos(half_angle_rad)) * i / points
    phi = math.pi * (1.0 + 5.0 ** 0.5) * i
    return np.column_stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])


def brute_force_lit_angle(boresight, spacecraft, sun, radius) -> float:
    """
    Return the smallest separation (astropy) from the boresight to a visible, sunlit point of the sphere.

    A search over 200 000 points of the sphere, then over 200 000 points within 1 deg (from the
    Earth's centre) of the best one.
    """
    def best(surface):
        keep = (surface @ spacecraft > radius * radius) & (surface @ (sun / np.linalg.norm(sun)) > 0.0)
        if not keep.any():
            return math.inf, None
        lines = surface[keep] - spacecraft
        angles = separation_rad(lines, np.tile(boresight, (lines.shape[0], 1)))
        return float(angles.min()), surface[keep][int(np.argmin(angles))]

    coarse, point = best(radius * fibonacci_cap(200_000))
    if point is None:
        return math.inf
    patch = fibonacci_cap(200_000, math.radians(1.0))  # a cap about +z, rotated onto the best point
    axis = point / radius
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    fine, _ = best(radius * (patch[:, :1] * e1 + patch[:, 1:2] * e2 + patch[:, 2:] * axis))
    return min(coarse, fine)


def test_nearest_lit_point_of_the_earth_matches_a_brute_force_search():
    rng = np.random.default_rng(3)
    for _ in range(12):
        spacecraft = random_unit(rng) * (MODEL.earth_radius_m + rng.uniform(3e5, 2e6))
        sun = random_unit(rng) * AU_M
        earth = -spacecraft / np.linalg.norm(spacecraft)
        boresight = rotate_toward(earth, random_unit(rng), math.radians(rng.uniform(60.0, 110.0)))
        angle, direction = nearest_lit_earth(boresight, spacecraft, sun, LIMB_M)
        expected = brute_force_lit_angle(boresight, spacecraft, sun, LIMB_M)
        if math.isinf(expected):
            assert math.isinf(angle)
            continue
        assert angle == pytest.approx(expected, abs=math.radians(0.1))  # both searches sample
        assert separation_rad(direction, boresight)[0] == pytest.approx(angle, abs=1e-9)


def status_of(boresight, spacecraft, sun_direction, moon_direction=None) -> HeadStatus:
    moon = spacecraft + MOON_DISTANCE_M * (moon_direction if moon_direction is not None else -boresight)
    bodies = BodyPositions(spacecraft, spacecraft + AU_M * sun_direction, moon)
    return head_geometry(boresight, math.radians(10.0), bodies, MODEL).status


def test_status_follows_the_exclusion_angles():
    r = MODEL.earth_radius_m + 600e3
    spacecraft = np.array([0.0, 0.0, r])  # the Earth straight down (-z)
    zenith, x, y = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    rho = math.asin(LIMB_M / r)
    # The boresight on the Earth's disc: occulted, whatever else.
    assert status_of(rotate_toward(-zenith, x, rho - 0.01), spacecraft, y) == HeadStatus.OCCULTED
    # The Sun around its 30 deg exclusion (the Earth and the Moon far away).
    for angle, status in ((29.0, HeadStatus.BLINDED_SUN), (31.0, HeadStatus.TRACKING_POSSIBLE)):
        assert status_of(zenith, spacecraft, rotate_toward(zenith, x, math.radians(angle)), -x) == status
    # The Moon around its 25 deg exclusion (the Sun on the day side, behind the head).
    sun = rotate_toward(zenith, -y, math.radians(100.0))
    for angle, status in ((24.0, HeadStatus.BLINDED_MOON), (26.0, HeadStatus.TRACKING_POSSIBLE)):
        assert status_of(zenith, spacecraft, sun, rotate_toward(zenith, x, math.radians(angle))) == status
    # The lit limb around its 20 deg exclusion: over the day side (Sun overhead), then the night side.
    for above, status in ((19.0, HeadStatus.BLINDED_EARTH), (21.0, HeadStatus.TRACKING_POSSIBLE)):
        boresight = rotate_toward(-zenith, x, rho + math.radians(above))
        assert status_of(boresight, spacecraft, zenith, -boresight) == status
    night = rotate_toward(-zenith, x, rho + math.radians(5.0))
    assert status_of(night, spacecraft, -zenith, -night) == HeadStatus.TRACKING_POSSIBLE


def test_the_spacecraft_inside_the_earth_is_refused():
    with pytest.raises(ValueError, match="inside"):
        angular_radius(6.0e6, MODEL.limb_radius_m)
    with pytest.raises(ValueError):
        ExclusionModel(sun_exclusion_rad=-0.1)
