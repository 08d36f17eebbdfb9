# SPDX-License-Identifier: Apache-2.0
"""
Attitude modes and head mountings (sim/attitude_modes.py).

Geometry against the definitions (nadir boresight on the Earth's centre, the LVLH rate of a
circular orbit written out here, the Sun on its axis), and every angular_velocity_at against
central differences of rotations_at. Orbits and the Sun are stand-ins written here, or the
project's models (J2 Keplerian, SGP4, DE421), to show the modes take anything with state() and
sun_position().
"""
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from star_tracker.models.attitude import quaternion_to_matrix
from star_tracker.models.ephemeris import load_ephemeris
from star_tracker.models.orbit import KeplerianOrbit, OrbitElements, TleOrbit
from star_tracker.sim.attitude_modes import (ECLIPTIC_NORTH_ICRS, HeadMounting, MountedHeadMotion, NadirPointingMotion,
                                             SunPointingMotion, inertial_attitude)

MU = 3.986004418e14
AU = 149_597_870_700.0
EPOCH = 1.7e9
ISS = ("1 25544U 98067A   19343.69339541  .00001764  00000-0  38792-4 0  9991",
       "2 25544  51.6439 211.2001 0007417  17.6667  85.6398 15.50103472202482")


class CircularOrbit:
    """Two-body circular orbit of radius a [m], inclined about +X."""

    def __init__(self, radius: float, inclination: float) -> None:
        self.radius, self.rate = radius, math.sqrt(MU / radius**3)
        c, s = math.cos(inclination), math.sin(inclination)
        self.plane = np.array([[1.0, 0.0], [0.0, c], [0.0, s]])

    def state(self, times):
        u = self.rate * (np.asarray(times, dtype=float) - EPOCH)
        r = self.radius * np.stack([np.cos(u), np.sin(u)], axis=-1) @ self.plane.T
        v = self.radius * self.rate * np.stack([-np.sin(u), np.cos(u)], axis=-1) @ self.plane.T
        return r, v


class CircularSun:
    """The Sun on a circle of 1 au in the ecliptic, once a year."""

    def sun_position(self, times):
        angle = 2 * np.pi * (np.asarray(times, dtype=float) - EPOCH) / (365.25 * 86400.0)
        x_axis = np.array([1.0, 0.0, 0.0])
        y_axis = np.cross(ECLIPTIC_NORTH_ICRS, x_axis)
        return AU * (np.multiply.outer(np.cos(angle), x_axis) + np.multiply.outer(np.sin(angle), y_axis))


def _finite_difference_rate(profile, t: float, h: float) -> np.ndarray:
    """Body rate [rad/s] from rotations h either side of t: log(R(t-h)^T R(t+h)) / 2h."""
    before, after = profile.rotations_at(np.array([t - h, t + h]))
    return Rotation.from_matrix(before.T @ after).as_rotvec() / (2 * h)


def _assert_rotations(rotations: np.ndarray) -> None:
    assert np.allclose(np.transpose(rotations, (0, 2, 1)) @ rotations, np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(rotations), 1.0, atol=1e-12)


ORBITS = {"circular": lambda: CircularOrbit(6.9e6, 1.2),
          "j2-eccentric": lambda: KeplerianOrbit(OrbitElements(7.3e6, 0.05, 1.7, 0.3, 0.2, 1.0, EPOCH)),
          "sgp4": lambda: TleOrbit(*ISS)}


@pytest.mark.parametrize("name", ORBITS)
def test_nadir_boresight_points_at_the_earth_centre_along_the_orbit(name):
    orbit = ORBITS[name]()
    times = getattr(orbit, "epoch_unix_s", EPOCH) + np.linspace(0.0, 6000.0, 40)
    rotations = NadirPointingMotion(orbit).rotations_at(times)
    r, v = orbit.state(times)
    _assert_rotations(rotations)
    assert np.allclose(rotations[:, :, 2], -r / np.linalg.norm(r, axis=1, keepdims=True), atol=1e-14)
    normal = np.cross(r, v)
    assert np.allclose(rotations[:, :, 1], -normal / np.linalg.norm(normal, axis=1, keepdims=True), atol=1e-14)
    assert np.all(np.sum(rotations[:, :, 0] * v, axis=1) > 0.99 * np.linalg.norm(v, axis=1))  # along the velocity


def test_lvlh_turns_at_the_orbital_rate_about_minus_y():
    orbit = CircularOrbit(6.9e6, 1.2)
    motion = NadirPointingMotion(orbit)
    for t in EPOCH + np.array([0.0, 1234.5, 4000.0]):
        assert np.allclose(motion.angular_velocity_at(t), [0.0, -orbit.rate, 0.0], rtol=0, atol=1e-12 * orbit.rate)
    # Over a quarter period the boresight turns 90 degrees, about body Y.
    quarter = motion.rotations_at(EPOCH + np.array([0.0, 0.5 * np.pi / orbit.rate]))
    turn = Rotation.from_matrix(quarter[0].T @ quarter[1]).as_rotvec()
    assert np.allclose(turn, [0.0, -np.pi / 2, 0.0], atol=1e-9)


@pytest.mark.parametrize("name", ORBITS)
def test_nadir_rates_match_differences_of_the_rotations(name):
    orbit = ORBITS[name]()
    motion = NadirPointingMotion(orbit)
    for t in getattr(orbit, "epoch_unix_s", EPOCH) + np.array([0.0, 1000.0, 3000.0]):
        rate = motion.angular_velocity_at(t)
        assert np.max(np.abs(rate - _finite_difference_rate(motion, t, 0.5))) < 1e-10
    if name != "circular":  # the orbit plane turns: a roll about the boresight shows
        assert abs(rate[2]) > 1e-7


@pytest.mark.parametrize("orbit_name, sun_name", [("circular", "stand-in"), ("sgp4", "de421")])
def test_sun_pointing_puts_the_axis_on_the_sun_and_the_roll_on_the_reference(orbit_name, sun_name):
    orbit = ORBITS[orbit_name]()
    sun = CircularSun() if sun_name == "stand-in" else load_ephemeris()
    motion = SunPointingMotion(orbit, sun)
    times = getattr(orbit, "epoch_unix_s", EPOCH) + np.linspace(0.0, 86400.0 * 40, 25)
    rotations = motion.rotations_at(times)
    _assert_rotations(rotations)
    to_sun = sun.sun_position(times) - orbit.state(times)[0]
    to_sun /= np.linalg.norm(to_sun, axis=1, keepdims=True)
    assert np.allclose(rotations[:, :, 2], to_sun, atol=1e-14)
    # Body +X: the ecliptic pole's part across the Sun direction, i.e. as close to the pole as it can be.
    across = ECLIPTIC_NORTH_ICRS - (to_sun @ ECLIPTIC_NORTH_ICRS)[:, None] * to_sun
    assert np.allclose(rotations[:, :, 0], across / np.linalg.norm(across, axis=1, keepdims=True), atol=1e-12)
    for t in times[:3]:
        rate = motion.angular_velocity_at(t)
        assert np.max(np.abs(rate - _finite_difference_rate(motion, t, 20.0))) < 1e-10
        assert 1e-7 < np.linalg.norm(rate) < 1e-6  # the Sun's apparent motion: ~1 deg a day


def test_sun_pointing_with_other_axes_and_a_degenerate_reference():
    orbit, sun = CircularOrbit(7.0e6, 0.5), CircularSun()
    motion = SunPointingMotion(orbit, sun, sun_axis=[0.0, -1.0, 0.0], reference_axis=[0.3, 0.0, 1.0],
                               reference_icrs=[0.0, 0.0, 1.0])
    rotation = motion.rotation_at(EPOCH + 5e6)
    to_sun = sun.sun_position(EPOCH + 5e6) - orbit.state(EPOCH + 5e6)[0]
    assert np.allclose(rotation @ [0.0, -1.0, 0.0], to_sun / np.linalg.norm(to_sun), atol=1e-14)
    assert (rotation @ [0.0, 0.0, 1.0])[2] > 0.9  # body +Z (reference_axis made perpendicular) toward ICRS north
    rate = motion.angular_velocity_at(EPOCH + 5e6)
    assert np.max(np.abs(rate - _finite_difference_rate(motion, EPOCH + 5e6, 20.0))) < 1e-10
    along = SunPointingMotion(orbit, sun, reference_icrs=[1.0, 0.0, 0.0])  # the stand-in Sun is at +X at EPOCH
    with pytest.raises(ValueError, match="reference_icrs is along the Sun direction"):
        along.rotation_at(EPOCH)
    with pytest.raises(ValueError, match="reference_axis must not be along sun_axis"):
        SunPointingMotion(orbit, sun, reference_axis=[0.0, 0.0, 2.0])
    with pytest.raises(ValueError, match="ephemeris must have sun_position"):
        SunPointingMotion(orbit, object())
    with pytest.raises(ValueError, match="orbit must have state"):
        NadirPointingMotion(object())


def test_head_mounting_composes_with_the_body_attitude():
    body = NadirPointingMotion(ORBITS["j2-eccentric"]())
    # Head boresight along body -X (looking backward), head +X (right) along body +Z, head +Y = Z x X.
    matrix = np.column_stack([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    mounting = HeadMounting(matrix)
    head = MountedHeadMotion(body, mounting)
    times = EPOCH + np.array([0.0, 700.0, 2500.0])
    body_rotations, head_rotations = body.rotations_at(times), head.rotations_at(times)
    assert np.allclose(head_rotations[:, :, 2], -body_rotations[:, :, 0], atol=1e-15)
    assert np.allclose(head_rotations, body_rotations @ matrix, atol=1e-15)
    for t in times:
        assert np.allclose(head.angular_velocity_at(t), matrix.T @ body.angular_velocity_at(t), atol=1e-18)
        assert np.max(np.abs(head.angular_velocity_at(t) - _finite_difference_rate(head, t, 0.5))) < 1e-10
    again = HeadMounting.from_quaternion(mounting.quaternion)
    assert np.allclose(again.head_to_body, matrix, atol=1e-15)
    q = Rotation.from_euler("zyx", [0.3, -0.2, 1.1]).as_quat()  # scipy: (x, y, z, w), like ROS
    assert np.allclose(HeadMounting.from_quaternion(q).head_to_body, quaternion_to_matrix(q), atol=1e-15)


def test_bad_mountings_are_refused():
    with pytest.raises(ValueError, match="proper rotation"):
        HeadMounting(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="orthonormal"):
        HeadMounting(np.diag([1.0, 1.0, 1.01]))
    with pytest.raises(ValueError, match="head_to_body must have shape"):
        HeadMounting(np.eye(4))
    with pytest.raises(ValueError, match="unit quaternion"):
        HeadMounting.from_quaternion([0.0, 0.0, 0.0, 2.0])
    with pytest.raises(ValueError, match="q_xyzw must be finite"):
        HeadMounting.from_quaternion([0.0, 0.0, np.nan, 1.0])
    with pytest.raises(ValueError, match="mounting must be a HeadMounting"):
        MountedHeadMotion(inertial_attitude(np.eye(3)), np.eye(3))


def test_inertial_attitude_stays_put():
    rotation = Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_matrix()
    motion = inertial_attitude(rotation)
    assert np.allclose(motion.rotations_at(EPOCH + np.array([0.0, 1e5])), rotation, atol=1e-15)
    assert np.array_equal(motion.angular_velocity_at(EPOCH), np.zeros(3))
    with pytest.raises(ValueError, match="rotation must be a rotation matrix"):
        inertial_attitude(np.diag([1.0, -1.0, 1.0]))
