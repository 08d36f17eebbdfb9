# SPDX-License-Identifier: Apache-2.0
"""
The observer's state at a frame's stamp (models/observer_state.py), against an orbit and ERFA.

Samples of a 550 km circular orbit (models.orbit) 1 s apart: the state extrapolated to a stamp
between them, or a minute past the last, is the orbit's within metres; a stamp past max_age_s
has none; bad samples are
refused with the reason. The observer's barycentric velocity is the Earth's (ERFA's epv00, an
ephemeris independent of the DE421 one the product reads) plus the orbital one.
"""
from __future__ import annotations

import math

import erfa
import numpy as np
import pytest

from star_tracker.models.ephemeris import load_ephemeris
from star_tracker.models.observer_state import ObserverSky, ObserverTrack
from star_tracker.models.orbit import KeplerianOrbit, OrbitElements

EPOCH = 1_796_000_000.0  # 2026-12-01
ORBIT = KeplerianOrbit(OrbitElements.circular(550e3, math.radians(97.6), epoch_unix_s=EPOCH))


def track_of(times_s, max_age_s=5.0) -> ObserverTrack:
    track = ObserverTrack(max_age_s)
    for t in times_s:
        r, v = ORBIT.state(t)
        track.add(int(round(t * 1e9)), r, v)
    return track


def test_the_state_between_samples_is_the_orbits_within_metres():
    track = track_of(EPOCH + np.arange(10.0))
    for dt in (0.25, 0.5, 0.99):
        t = EPOCH + 4 + dt
        state = track.at(int(round(t * 1e9)))
        r, v = ORBIT.state(t)
        assert np.linalg.norm(state.position_m - r) < 5.0  # |a| dt^2 / 2 = 8.4 m/s^2 x 0.5 s^2
        assert np.linalg.norm(state.velocity_m_s - v) < 10.0


def test_a_minute_from_the_last_sample_the_state_is_the_orbits_within_metres():
    """Odometry lost for a minute: the velocity stays within 2 m/s (0.0014" of aberration) of the J2 orbit's."""
    track = track_of(EPOCH + np.arange(3.0), max_age_s=120.0)
    for dt in (10.0, 30.0, 60.0):
        t = EPOCH + 2 + dt
        state = track.at(int(round(t * 1e9)))
        r, v = ORBIT.state(t)
        assert np.linalg.norm(state.velocity_m_s - v) < 2.0, dt  # 1.3 m/s measured at 60 s: J2, not in the step
        assert np.linalg.norm(state.position_m - r) < 100.0, dt


def test_a_stale_track_has_no_state_and_bad_samples_are_refused():
    track = track_of(EPOCH + np.arange(3.0), max_age_s=2.0)
    assert track.at(int((EPOCH + 3.5) * 1e9)) is not None
    assert track.at(int((EPOCH + 4.5) * 1e9)) is None
    r, v = ORBIT.state(EPOCH + 10)
    with pytest.raises(ValueError, match="not newer"):
        track.add(int(EPOCH * 1e9), r, v)
    with pytest.raises(ValueError, match="geocentric position in metres"):
        track.add(int((EPOCH + 10) * 1e9), r / 1e3, v)
    with pytest.raises(ValueError, match="finite"):
        track.add(int((EPOCH + 10) * 1e9), r, v * np.nan)
    with pytest.raises(ValueError, match="max_age_s"):
        ObserverTrack(0.0)


def test_the_barycentric_velocity_is_the_earths_plus_the_orbital_one():
    sky = ObserverSky(load_ephemeris())
    track = track_of([EPOCH])
    state = track.at(int(EPOCH * 1e9))
    # The stamp as UTC, then TAI (ERFA's own leap seconds), TT; TDB - TT < 2 ms is neglected.
    tai = erfa.utctai(2440587.5, EPOCH / 86400.0)
    pvh, pvb = erfa.epv00(*erfa.taitt(*tai))
    earth_velocity = np.asarray(pvb[1]) * 149_597_870_700.0 / 86400.0  # [au/d] -> [m/s]
    velocity = sky.barycentric_velocity(state)
    assert np.linalg.norm(velocity - (earth_velocity + state.velocity_m_s)) < 0.02
    bodies = sky.bodies(state)
    assert np.array_equal(bodies.spacecraft_m, state.position_m)
    assert 1.47e11 < np.linalg.norm(bodies.sun_m) < 1.52e11 and 3.5e8 < np.linalg.norm(bodies.moon_m) < 4.1e8
