# SPDX-License-Identifier: Apache-2.0
"""
A head's per-frame status (track/head_status.py) from what it did and the bodies' geometry.

Geometry built here from plain vectors (a spacecraft at 550 km, the Sun and Moon at their
distances): a frame without an attitude says why when the geometry knows (the boresight on the
Earth, at the Sun, at the lit limb, at the Moon), else whether the rate is too high, else that
the head is searching; a frame with an attitude is tracking or lost-in-space whatever the
geometry.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from star_tracker.models.sky_geometry import BodyPositions, ExclusionModel, head_geometry
from star_tracker.track.head_status import (BLINDED_EARTH, BLINDED_MOON, BLINDED_SUN, ERROR, LOST_IN_SPACE, OCCULTED,
                                            OK, RATE_TOO_HIGH, TRACKING, WARN, head_frame_status)

AU, MOON_DISTANCE, R_SC = 1.496e11, 3.844e8, 6_928_137.0
SPACECRAFT = np.array([R_SC, 0.0, 0.0])
SUN = AU * np.array([0.0, 1.0, 0.0])  # the spacecraft in daylight, the Sun along +Y
MOON = MOON_DISTANCE * np.array([0.0, 0.0, 1.0])
BODIES = BodyPositions(SPACECRAFT, SUN, MOON)
HALF_FOV = math.radians(10.0)
MAX_RATE = math.radians(3.0)


def tilted(axis: np.ndarray, towards: np.ndarray, angle_deg: float) -> np.ndarray:
    """Return the unit vector `angle_deg` from `axis` toward `towards`."""
    axis = axis / np.linalg.norm(axis)
    other = towards - axis * (towards @ axis)
    other /= np.linalg.norm(other)
    a = math.radians(angle_deg)
    return math.cos(a) * axis + math.sin(a) * other


def geometry(boresight):
    return head_geometry(np.asarray(boresight, float), HALF_FOV, BODIES, ExclusionModel())


@pytest.mark.parametrize("boresight, expected", [
    (-SPACECRAFT / R_SC, OCCULTED),  # straight down at the Earth's centre
    (tilted(np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 10.0), BLINDED_SUN),  # 10 deg from the Sun
    (tilted(np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0]), 5.0), BLINDED_MOON),  # 5 deg from the Moon
])
def test_a_frame_without_an_attitude_says_why(boresight, expected):
    status = head_frame_status(None, geometry(boresight), None, MAX_RATE)
    assert (status.status, status.level, status.attitude) == (expected, ERROR, False)
    assert status.predicted == expected


def test_the_lit_limb_blinds_and_the_angles_are_the_geometrys():
    # The Sun behind the spacecraft: the Earth below is lit to its limb. The limb (Earth + 100 km)
    # lies arccos(R / r) below the local horizontal; the boresight 5 deg above it.
    sun = AU * np.array([1.0, 0.0, 0.0])
    bodies = BodyPositions(SPACECRAFT, sun, MOON)
    down = -SPACECRAFT / R_SC
    limb_from_nadir = 90.0 - math.degrees(math.acos(6_478_137.0 / R_SC))
    boresight = tilted(down, np.array([0.0, 0.0, -1.0]), limb_from_nadir + 5.0)
    g = head_geometry(boresight, HALF_FOV, bodies, ExclusionModel())
    status = head_frame_status(None, g, None, MAX_RATE)
    assert (status.status, status.level) == (BLINDED_EARTH, ERROR)
    assert status.earth_limb_angle_rad == pytest.approx(math.radians(5.0), abs=1e-6)
    assert status.sun_angle_rad == pytest.approx(float(np.arccos(boresight @ sun / np.linalg.norm(sun))), abs=1e-9)


def test_with_an_attitude_the_head_is_tracking_or_lost_in_space_whatever_the_geometry():
    at_sun = geometry(tilted(np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 10.0))
    assert head_frame_status(TRACKING, at_sun, None, MAX_RATE).status == TRACKING
    solved = head_frame_status(LOST_IN_SPACE, at_sun, None, MAX_RATE)
    assert (solved.status, solved.level, solved.attitude) == (LOST_IN_SPACE, OK, True)


def test_clear_sky_without_an_attitude_is_rate_too_high_or_searching():
    clear = geometry(tilted(np.array([0.0, 0.0, -1.0]), np.array([0.0, -1.0, 0.0]), 30.0))
    assert clear.status.value == "tracking_possible"
    fast = head_frame_status(None, clear, np.radians([4.0, 0.0, 0.0]), MAX_RATE)
    assert (fast.status, fast.level) == (RATE_TOO_HIGH, ERROR)
    assert fast.rate_rad_s == pytest.approx(math.radians(4.0))
    slow = head_frame_status(None, clear, np.radians([1.0, 0.0, 0.0]), MAX_RATE)
    assert (slow.status, slow.level) == (LOST_IN_SPACE, WARN)
    unknown = head_frame_status(None, None, None, MAX_RATE)
    assert (unknown.status, unknown.predicted) == (LOST_IN_SPACE, "unknown") and math.isnan(unknown.sun_angle_rad)
