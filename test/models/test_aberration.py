# SPDX-License-Identifier: Apache-2.0
"""
Aberration and the Sun's light deflection (models/aberration.py) against ERFA and astropy.

Our formulas against ERFA's eraAb and eraLdsun for random directions and velocities, the exact
inverses, and the end-to-end apparent place of stars against astropy's ICRS -> GCRS transform for
an observer in orbit (obsgeoloc, obsgeovel; astropy takes the Earth's velocity from its own
builtin ephemeris, ERFA epv00). Measured (pytest -s prints them): 6e-7 arcsec against eraAb,
< 1e-9 against eraLdsun, 2e-6 arcsec end to end.
"""
import astropy.units as u
import erfa
import numpy as np
import pytest
from astropy.coordinates import GCRS, ICRS, CartesianRepresentation
from astropy.time import Time
from astropy.utils import iers

from star_tracker.models.aberration import (ASTRONOMICAL_UNIT_M, SPEED_OF_LIGHT_M_S, aberrate, apparent_directions,
                                            astrometric_directions, deflect_by_sun, unaberrate, undeflect_by_sun)
from star_tracker.models.ephemeris import load_ephemeris

ARCSEC = np.pi / 180 / 3600


def _angle(a, b) -> np.ndarray:
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _unit(rng, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_aberration_matches_erfa_ab_and_inverts_exactly():
    rng = np.random.default_rng(11)
    directions = _unit(rng, 500)
    # Orbital, the Earth's, their sum at 1 au from the Sun; and 1 % of c far from it, where ERFA's
    # solar-potential term (2e-8 |v|/c rad, which we leave out) vanishes: the relativistic terms show.
    for speed, sun_distance_au in ((7.7e3, 1.0), (30e3, 1.0), (45e3, 1.0), (3e6, 1e9)):
        velocity = _unit(rng, 1)[0] * speed
        beta = velocity / SPEED_OF_LIGHT_M_S
        reference = erfa.ab(directions, beta, sun_distance_au, np.sqrt(1 - beta @ beta))
        apparent = aberrate(directions, velocity)
        error = np.max(_angle(apparent, reference)) / ARCSEC
        round_trip = np.max(_angle(unaberrate(apparent, velocity), directions)) / ARCSEC
        print(f"measured: aberration at {speed / 1e3:g} km/s {error:.2g} arcsec from erfa.ab, "
              f"round trip {round_trip:.2g}")
        assert error < 1e-5 and round_trip < 1e-6
        assert np.allclose(np.linalg.norm(apparent, axis=1), 1.0, atol=1e-15)


def test_aberration_size_and_sense():
    # 30 km/s across the line of sight: v/c = 20.6 arcsec, toward the velocity; none along it.
    velocity = np.array([0.0, 30e3, 0.0])
    apparent = aberrate(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), velocity)
    assert _angle(apparent[0], [1.0, 0.0, 0.0]) / ARCSEC == pytest.approx(20.64, abs=0.01)
    assert apparent[0, 1] > 0 and _angle(apparent[1], [0.0, 1.0, 0.0]) < 1e-15
    assert aberrate([1.0, 0.0, 0.0], velocity).shape == (3,)


def test_deflection_matches_erfa_ldsun_and_inverts():
    rng = np.random.default_rng(12)
    directions = _unit(rng, 2000)
    for distance_au in (0.983, 1.0, 1.017, 0.4):
        sun = _unit(rng, 1)[0] * distance_au * ASTRONOMICAL_UNIT_M
        reference = erfa.ldsun(directions, -sun / np.linalg.norm(sun), distance_au)
        deflected = deflect_by_sun(directions, sun)
        assert np.max(_angle(deflected, reference)) / ARCSEC < 1e-6
        assert np.max(_angle(undeflect_by_sun(deflected, sun), directions)) / ARCSEC < 1e-6
    # 1.75 arcsec at the solar limb (0.2666 deg from the centre at 1 au), away from the Sun.
    sun = np.array([ASTRONOMICAL_UNIT_M, 0.0, 0.0])
    limb = np.array([np.cos(np.radians(0.2666)), np.sin(np.radians(0.2666)), 0.0])
    deflected = deflect_by_sun(limb, sun)
    assert _angle(deflected, limb) / ARCSEC == pytest.approx(1.75, abs=0.01) and deflected[1] > limb[1]


def test_apparent_stars_for_an_orbiting_observer_match_astropy_gcrs():
    ephemeris = load_ephemeris()
    rng = np.random.default_rng(13)
    with iers.conf.set_temp("auto_download", False):
        for unix in rng.uniform(1.0e9, 1.9e9, 6):
            position = _unit(rng, 1)[0] * 6.9e6
            velocity = np.cross(position, _unit(rng, 1)[0])
            velocity *= 7.6e3 / np.linalg.norm(velocity)
            stars = _unit(rng, 400)
            frame = GCRS(obstime=Time(unix, format="unix"), obsgeoloc=CartesianRepresentation(position * u.m),
                         obsgeovel=CartesianRepresentation(velocity * u.m / u.s))
            reference = ICRS(CartesianRepresentation(stars.T)).transform_to(frame).cartesian.xyz.value.T
            total_velocity = ephemeris.earth_velocity(unix) + velocity
            sun = ephemeris.sun_position(unix, observer_m=position)
            apparent = apparent_directions(stars, total_velocity, sun)
            far = _angle(stars, sun) > np.radians(30)
            print(f"measured: apparent stars {np.max(_angle(apparent, reference)) / ARCSEC:.2g} arcsec from astropy "
                  f"GCRS; aberration alone >30 deg from the Sun "
                  f"{np.max(_angle(aberrate(stars, total_velocity), reference)[far]) / ARCSEC:.2g} arcsec")
            assert np.max(_angle(apparent, reference)) / ARCSEC < 0.001
            assert np.max(_angle(astrometric_directions(apparent, total_velocity, sun), stars)) / ARCSEC < 1e-6
            # Aberration alone, the renderer's cheaper choice, is within 0.05 arcsec 30 deg from the Sun.
            assert np.max(_angle(aberrate(stars, total_velocity), reference)[far]) / ARCSEC < 0.05


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="directions"):
        aberrate(np.ones((4, 2)), [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="unit vectors"):
        aberrate([[2.0, 0.0, 0.0]], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="velocity_m_s"):
        aberrate([[1.0, 0.0, 0.0]], [np.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match="slower than light"):
        aberrate([[1.0, 0.0, 0.0]], [SPEED_OF_LIGHT_M_S, 0.0, 0.0])
    with pytest.raises(ValueError, match="sun_from_observer_m"):
        deflect_by_sun([[1.0, 0.0, 0.0]], [0.0, 0.0, 0.0])
