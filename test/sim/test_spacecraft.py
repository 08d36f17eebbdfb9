# SPDX-License-Identifier: Apache-2.0
"""
A spacecraft in orbit and its heads (sim/spacecraft.py), against the orbit's geometry and ERFA.

A nadir-pointing spacecraft on a 550 km sun-synchronous orbit: a head mounted along the body's
+Z looks at the Earth's centre, one mounted on the zenith side 45 deg off it looks 45 deg from
zenith; a misaligned head's true attitude is its nominal one turned by the misalignment (offset
plus drift); the frame's environment carries the orbit's state and the observer's barycentric
velocity, which is ERFA's Earth velocity (epv00) plus the orbital one.
"""
from __future__ import annotations

import math

import erfa
import numpy as np
import pytest

from star_tracker.models.attitude import attitude_error, rotation_vector_to_matrix
from star_tracker.models.ephemeris import load_ephemeris
from star_tracker.models.orbit import KeplerianOrbit, OrbitElements, sun_synchronous_inclination
from star_tracker.sim.attitude_modes import HeadMounting, NadirPointingMotion
from star_tracker.sim.spacecraft import Misalignment, Spacecraft

T0 = 1_796_000_000.0
ORBIT = KeplerianOrbit(OrbitElements.circular(550e3, sun_synchronous_inclination(550e3), epoch_unix_s=T0))
ARCSEC = math.radians(1 / 3600)
ZENITH_45 = HeadMounting(rotation_vector_to_matrix(np.array([math.radians(135.0), 0.0, 0.0])))  # +Z -> 45 deg from -Z


def spacecraft(**kwargs) -> Spacecraft:
    return Spacecraft(ORBIT, NadirPointingMotion(ORBIT), {"nadir": HeadMounting(np.eye(3)), "sky": ZENITH_45},
                      load_ephemeris(), **kwargs)


def test_heads_look_where_their_mountings_put_them():
    craft = spacecraft()
    for t in T0 + np.array([0.0, 1000.0, 3000.0]):
        r, _ = ORBIT.state(t)
        nadir = craft.head_motion("nadir").rotation_at(t)[:, 2]
        assert np.degrees(np.arccos(nadir @ (-r / np.linalg.norm(r)))) < 1e-6
        sky = craft.head_motion("sky").rotation_at(t)[:, 2]
        assert np.degrees(np.arccos(sky @ (r / np.linalg.norm(r)))) == pytest.approx(45.0, abs=1e-6)


def test_a_misaligned_head_is_turned_by_its_offset_and_drift():
    drift = Misalignment(offset_rad=(10 * ARCSEC, 0.0, 0.0), drift_amplitude_rad=(0.0, 3 * ARCSEC, 0.0),
                         drift_period_s=ORBIT.period_s, drift_epoch_unix_s=T0)
    nominal, misaligned = spacecraft(), spacecraft(misalignments={"sky": drift})
    quarter = T0 + ORBIT.period_s / 4  # the drift at its peak
    error = attitude_error(misaligned.head_motion("sky").rotation_at(quarter),
                           nominal.head_motion("sky").rotation_at(quarter))
    assert math.hypot(10.0, 3.0) * ARCSEC == pytest.approx(error[2], rel=1e-6)
    with pytest.raises(ValueError, match="unknown heads"):
        spacecraft(misalignments={"other": drift})


def test_the_environment_is_the_orbits_and_the_observer_velocity_erfas_plus_orbital():
    env = spacecraft().environment(T0 + 500.0)
    r, v = ORBIT.state(T0 + 500.0)
    assert np.array_equal(env.spacecraft_position_m, r) and np.array_equal(env.spacecraft_velocity_m_s, v)
    _, pvb = erfa.epv00(*erfa.taitt(*erfa.utctai(2440587.5, (T0 + 500.0) / 86400.0)))
    earth = np.asarray(pvb[1]) * 149_597_870_700.0 / 86400.0
    assert np.linalg.norm(env.observer_velocity_m_s - (earth + v)) < 0.02
    assert env.planet_magnitudes.size == 5 and np.all(env.planet_magnitudes < 2.0)
