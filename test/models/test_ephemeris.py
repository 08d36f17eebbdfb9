# SPDX-License-Identifier: Apache-2.0
"""
Sun, Moon and planets (models/ephemeris.py: DE421 through skyfield) against astropy's own ephemeris.

The reference is astropy's solar_system_ephemeris 'builtin' (ERFA epv00 for the Earth and Sun,
moon98 for the Moon, plan94 for the planets): no skyfield and no JPL file, so a mistake in our
time conversion, light time, frame or units shows. Tolerances are the builtin models' own
accuracy over 1972-2053 (UTC is well defined from 1972) with a margin; measured here (pytest -s
prints them): Sun 0.011 arcsec, Moon 8.5, Mercury 1.3, Venus 9.9, Mars 48, Jupiter 50, Saturn 88
arcsec; the Earth's velocity 3.4 mm/s (a denser sample of 400 times: Sun 0.04, Moon 11, Saturn
89 arcsec, 6 mm/s).
"""
import subprocess
import sys
import warnings
from datetime import datetime, timezone

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import (EarthLocation, get_body, get_body_barycentric, get_body_barycentric_posvel,
                                 solar_system_ephemeris)
from astropy.time import Time
from astropy.utils import iers

from star_tracker.models.aberration import aberrate
from star_tracker.models.ephemeris import BODIES, PLANETS, Ephemeris, load_ephemeris

ARCSEC = np.pi / 180 / 3600
C = 299_792_458.0
UTC_1972 = 63_072_000.0
# Tolerance [arcsec] on the direction: the builtin models' accuracy with a margin (measured maxima in the
# module docstring). A missing light time shifts the Sun by 20 arcsec.
DIRECTION_TOLERANCE = {"sun": 0.1, "moon": 20.0, "mercury": 3.0, "venus": 15.0, "mars": 75.0, "jupiter": 90.0,
                       "saturn": 120.0}
DISTANCE_TOLERANCE = {"sun": 1e-6, "moon": 1e-4, "mercury": 3e-5, "venus": 1e-4, "mars": 3e-4, "jupiter": 3e-4,
                      "saturn": 3e-4}


@pytest.fixture(autouse=True)
def offline_astropy():
    """Astropy must not fetch IERS tables (no network); it warns on far-future UTC ('dubious year')."""
    with iers.conf.set_temp("auto_download", False), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*dubious year.*")
        with solar_system_ephemeris.set("builtin"):
            yield


@pytest.fixture(scope="module")
def ephemeris():
    return load_ephemeris()


@pytest.fixture(scope="module")
def times(ephemeris):
    """UNIX seconds spread over 1972 .. the end of the span."""
    return np.sort(np.random.default_rng(7).uniform(UTC_1972, ephemeris.span_unix_s[1], 150))


def _unix(iso: str) -> float:
    return datetime.fromisoformat(iso).replace(tzinfo=timezone.utc).timestamp()


def _angle(a, b) -> np.ndarray:
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def builtin_astrometric(body: str, unix: np.ndarray) -> np.ndarray:
    """Geocentric astrometric vector [m] from astropy's builtin ephemeris: the body at t - light time."""
    t = Time(unix, format="unix")
    earth = get_body_barycentric("earth", t)
    light_time = np.zeros(np.shape(unix))
    for _ in range(4):
        vector = (get_body_barycentric(body, t - light_time * u.s) - earth).xyz.to_value(u.m).T
        light_time = np.linalg.norm(vector, axis=-1) / C
    return vector


@pytest.mark.parametrize("body", BODIES)
def test_direction_and_distance_against_astropy_builtin(ephemeris, times, body):
    ours = ephemeris.position(body, times)
    reference = builtin_astrometric(body, times)
    worst = np.max(_angle(ours, reference)) / ARCSEC
    ratio = np.linalg.norm(ours, axis=-1) / np.linalg.norm(reference, axis=-1)
    print(f"measured: {body} direction {worst:.3g} arcsec, distance {np.max(np.abs(ratio - 1)):.2g} (relative) "
          f"from astropy builtin")
    assert worst < DIRECTION_TOLERANCE[body], f"{body}: {worst:.3f} arcsec"
    assert np.max(np.abs(ratio - 1)) < DISTANCE_TOLERANCE[body]


def test_earth_barycentric_velocity_against_erfa_epv00(ephemeris, times):
    _, velocity = get_body_barycentric_posvel("earth", Time(times, format="unix"))  # builtin: ERFA epv00
    reference = velocity.xyz.to_value(u.m / u.s).T
    error = np.linalg.norm(ephemeris.earth_velocity(times) - reference, axis=-1)
    print(f"measured: Earth's barycentric velocity {np.max(error) * 1e3:.2g} mm/s from ERFA epv00")
    assert np.max(error) < 0.01  # 6 mm/s measured: 2e-8 arcsec of aberration
    assert np.all(np.abs(np.linalg.norm(reference, axis=-1) - 29.8e3) < 0.6e3)


def test_moon_seen_from_orbit_against_astropy_topocentric(ephemeris):
    # A ground station stands in for a spacecraft: astropy places it in GCRS itself (its own Earth
    # rotation), the parallax is ~1 deg, and astropy's GCRS direction is apparent: aberrate ours.
    station = EarthLocation.from_geodetic(lon=30 * u.deg, lat=-20 * u.deg, height=400 * u.km)
    unix = np.linspace(_unix("2019-03-01T00:00:00"), _unix("2024-06-01T00:00:00"), 12)
    t = Time(unix, format="unix")
    position, velocity = station.get_gcrs_posvel(t)
    observer = position.xyz.to_value(u.m).T
    reference = get_body("moon", t, location=station).cartesian.xyz.to_value(u.m).T
    apparent = [aberrate(v / np.linalg.norm(v), w + o) for v, w, o in
                zip(ephemeris.moon_position(unix, observer_m=observer), ephemeris.earth_velocity(unix),
                    velocity.xyz.to_value(u.m / u.s).T)]
    geocentric = ephemeris.moon_position(unix)
    assert np.min(_angle(geocentric, reference)) > 0.5 * np.pi / 180  # the parallax is there to see
    print(f"measured: apparent Moon from 400 km {np.max(_angle(apparent, reference)) / ARCSEC:.3g} arcsec from "
          f"astropy get_body (topocentric, builtin)")
    assert np.max(_angle(apparent, reference)) / ARCSEC < DIRECTION_TOLERANCE["moon"]


def test_shapes_follow_the_times(ephemeris):
    t = np.array([1.6e9, 1.7e9, 1.8e9])
    assert ephemeris.sun_position(1.7e9).shape == (3,)
    assert ephemeris.moon_position(t).shape == (3, 3) and ephemeris.earth_velocity(t).shape == (3, 3)
    assert ephemeris.planet_magnitude("venus", t).shape == (3,)
    assert ephemeris.moon_illuminated_fraction(1.7e9).shape == ()
    assert np.allclose(ephemeris.moon_position(t)[1], ephemeris.moon_position(1.7e9), rtol=1e-14, atol=0)


def test_moon_phase_and_sizes_against_published_dates(ephemeris):
    # Full and new moon of January 2024 (instants to the minute), the Sun's semi-diameter at perihelion
    # and aphelion 2024 (16.26' and 15.73'), and the Moon's against astropy's distance.
    assert ephemeris.moon_illuminated_fraction(_unix("2024-01-25T17:54:00")) > 0.99
    assert ephemeris.moon_illuminated_fraction(_unix("2024-01-11T11:57:00")) < 0.01
    arcmin = np.pi / 180 / 60
    assert ephemeris.sun_angular_radius(_unix("2024-01-03T00:00:00")) / arcmin == pytest.approx(16.26, abs=0.02)
    assert ephemeris.sun_angular_radius(_unix("2024-07-05T00:00:00")) / arcmin == pytest.approx(15.73, abs=0.02)
    unix = np.linspace(_unix("2024-01-01T00:00:00"), _unix("2024-02-01T00:00:00"), 20)
    radius = np.arcsin(1737.4e3 / np.linalg.norm(builtin_astrometric("moon", unix), axis=-1))
    assert np.max(np.abs(ephemeris.moon_angular_radius(unix) - radius)) / ARCSEC < 0.5
    assert 14.6 * arcmin < radius.min() and radius.max() < 16.8 * arcmin


def test_moon_illuminated_fraction_against_astropy_geometry(ephemeris, times):
    sun, moon = builtin_astrometric("sun", times), builtin_astrometric("moon", times)
    reference = 0.5 * (1 + np.cos(_angle(sun - moon, -moon)))
    assert np.max(np.abs(ephemeris.moon_illuminated_fraction(times) - reference)) < 1e-4


def test_planet_magnitudes_against_published_oppositions(ephemeris, times):
    # Mars at its closest in 60 000 years (2003-08-28) and Jupiter at opposition 2023-11-03: -2.9.
    assert ephemeris.planet_magnitude("mars", _unix("2003-08-28T00:00:00")) == pytest.approx(-2.9, abs=0.1)
    assert ephemeris.planet_magnitude("jupiter", _unix("2023-11-03T00:00:00")) == pytest.approx(-2.9, abs=0.1)
    limits = {"venus": (-4.95, -3.0), "mars": (-2.95, 1.9), "jupiter": (-2.95, -1.6), "saturn": (-0.6, 1.5),
              "mercury": (-2.6, 7.5)}
    for planet in PLANETS:
        magnitude = ephemeris.planet_magnitude(planet, times)
        assert np.all(np.isfinite(magnitude)) and limits[planet][0] < magnitude.min() < magnitude.max() \
            < limits[planet][1], planet


def test_times_outside_the_span_are_refused_with_the_span(ephemeris):
    start, end = ephemeris.span_unix_s
    assert ephemeris.span_utc == ("1899-07-30", "2053-10-07")
    ephemeris.sun_position([start, end])
    for bad in (end + 86400.0, [1.7e9, start - 1.0]):
        with pytest.raises(ValueError, match="outside the ephemeris span 1899-07-30 .. 2053-10-07 UTC"):
            ephemeris.moon_position(bad)
    with pytest.raises(ValueError, match="finite"):
        ephemeris.earth_velocity(np.nan)
    with pytest.raises(ValueError, match="body must be one of"):
        ephemeris.position("pluto", 1.7e9)
    with pytest.raises(ValueError, match="body must be one of"):
        ephemeris.planet_magnitude("moon", 1.7e9)
    with pytest.raises(ValueError, match="observer_m"):
        ephemeris.moon_position(1.7e9, observer_m=[1.0, 2.0])
    with pytest.raises(ValueError, match="path"):
        Ephemeris("/nonexistent/de421.bsp")


def test_the_ephemeris_loads_once_and_not_on_import():
    assert load_ephemeris() is load_ephemeris()
    code = "import sys, star_tracker.models.ephemeris; print(sorted({'skyfield', 'jplephem'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
