# SPDX-License-Identifier: Apache-2.0
"""
Orbits (models/orbit.py) against independent computations.

Keplerian states against a numerical integration of two-body motion (scipy DOP853) and an
independent state -> elements conversion; the J2 secular drift against a numerical integration with
the J2 acceleration (orbit-averaged node and perigee: the model's mean elements start the
integration as osculating ones, so the rates agree to ~1 %); the sun-synchronous inclination
against its definition and published values; TLE states against sgp4's raw TEME output rotated to
GCRS by astropy (not skyfield). Measured (pytest -s prints them): two-body < 6e-5 m over an orbit,
J2 node drift 0.1-1 %, TLE < 0.6 mm and < 4e-4 m/s.
"""
import math

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import GCRS, TEME, CartesianDifferential, CartesianRepresentation
from astropy.time import Time
from astropy.utils import iers
from scipy.integrate import solve_ivp
from scipy.optimize import brentq
from sgp4.api import Satrec

from star_tracker.models.orbit import (EARTH_EQUATORIAL_RADIUS_M, KeplerianOrbit, OrbitElements, TleOrbit,
                                       sun_synchronous_inclination, validate_tle)

MU = 3.986004418e14
J2 = 1.08262668e-3
EPOCH = 1.7e9
ISS = ("1 25544U 98067A   19343.69339541  .00001764  00000-0  38792-4 0  9991",
       "2 25544  51.6439 211.2001 0007417  17.6667  85.6398 15.50103472202482")
# SGP4 verification set (Vallado et al. 2006): a near-Earth eccentric orbit and a deep-space Molniya.
VANGUARD = ("1 00005U 58002B   00179.78495062  .00000023  00000-0  28098-4 0  4753",
            "2 00005  34.2682 348.7242 1859667 331.7664  19.3264 10.82419157413667")
MOLNIYA = ("1 08195U 75081A   06176.33215444  .00000099  00000-0  11873-3 0   813",
           "2 08195  64.1586 279.0717 6877146 264.7651  20.2257  2.00491383225656")
ELEMENTS = [OrbitElements.circular(500e3, math.radians(97.4), 1.0, 2.0, EPOCH),
            OrbitElements(12e6, 0.3, 0.9, 1.0, 2.0, 0.5, EPOCH),
            OrbitElements(26.6e6, 0.74, math.radians(63.4), 4.0, 4.7, 3.0, EPOCH)]


def _gravity(_t, y, j2: bool = False) -> np.ndarray:
    r = y[:3]
    radius = np.linalg.norm(r)
    acceleration = -MU * r / radius**3
    if j2:
        z2 = (r[2] / radius) ** 2
        scale = 1.5 * J2 * MU * EARTH_EQUATORIAL_RADIUS_M**2 / radius**5
        acceleration = acceleration + scale * r * np.array([5 * z2 - 1, 5 * z2 - 1, 5 * z2 - 3])
    return np.concatenate([y[3:], acceleration])


def _integrate(orbit, times, j2: bool = False) -> tuple[np.ndarray, np.ndarray]:
    solution = solve_ivp(_gravity, (times[0], times[-1]), np.concatenate(orbit.state(times[0])), method="DOP853",
                         rtol=1e-13 if not j2 else 1e-12, atol=1e-9 if not j2 else 1e-6, t_eval=times, args=(j2,))
    assert solution.success
    return solution.y[:3].T, solution.y[3:].T


def _elements(r, v) -> dict:
    """Classical elements of a state (the textbook algorithm, e.g. Vallado's RV2COE)."""
    h = np.cross(r, v)
    node = np.cross([0.0, 0.0, 1.0], h)
    e_vec = np.cross(v, h) / MU - r / np.linalg.norm(r)
    energy = v @ v / 2 - MU / np.linalg.norm(r)
    inclination = math.acos(h[2] / np.linalg.norm(h))
    raan = math.atan2(node[1], node[0]) % (2 * math.pi)
    h_hat = h / np.linalg.norm(h)

    def angle(a, b):  # from a to b, counter-clockwise about h
        return math.atan2(np.cross(a, b) @ h_hat, a @ b) % (2 * math.pi)
    return {"a": -MU / (2 * energy), "e": np.linalg.norm(e_vec), "i": inclination, "raan": raan,
            "argp": angle(node, e_vec), "nu": angle(e_vec, r), "u": angle(node, r)}


def _ascending_node(orbit, after: float) -> tuple[float, float]:
    """Time [s] and longitude [rad] of the first northward equator crossing after a time (positions only)."""
    times = after + np.linspace(0.0, orbit.period_s * 1.01, 400)
    z = orbit.state(times)[0][:, 2]
    k = int(np.flatnonzero((z[:-1] < 0) & (z[1:] >= 0))[0])
    crossing = brentq(lambda t: orbit.state(t)[0][2], times[k], times[k + 1], xtol=1e-9)
    r = orbit.state(crossing)[0]
    return crossing, math.atan2(r[1], r[0])


def _node_and_perigee(r, v) -> tuple[np.ndarray, np.ndarray]:
    """Unwrapped node longitude and argument of perigee [rad] of each state."""
    h = np.cross(r, v)
    node = np.stack([-h[:, 1], h[:, 0], np.zeros(len(h))], axis=1)
    node /= np.linalg.norm(node, axis=1, keepdims=True)
    e_vec = np.cross(v, h) / MU - r / np.linalg.norm(r, axis=1, keepdims=True)
    h_hat = h / np.linalg.norm(h, axis=1, keepdims=True)
    argp = np.arctan2(np.sum(np.cross(node, e_vec) * h_hat, axis=1), np.sum(node * e_vec, axis=1))
    return np.unwrap(np.arctan2(h[:, 0], -h[:, 1])), np.unwrap(argp)


@pytest.mark.parametrize("elements", ELEMENTS[1:], ids=["eccentric", "molniya"])
def test_state_at_epoch_has_the_given_elements(elements):
    found = _elements(*KeplerianOrbit(elements, j2_secular=False).state(elements.epoch_unix_s))
    assert found["a"] == pytest.approx(elements.semi_major_axis_m, rel=1e-12)
    assert found["e"] == pytest.approx(elements.eccentricity, abs=1e-12)
    for key, value in (("i", elements.inclination_rad), ("raan", elements.raan_rad),
                       ("argp", elements.arg_perigee_rad), ("nu", elements.true_anomaly_rad)):
        assert math.remainder(found[key] - value, 2 * math.pi) == pytest.approx(0.0, abs=1e-10), key


def test_circular_orbit_starts_at_its_argument_of_latitude():
    elements = ELEMENTS[0]
    r, v = KeplerianOrbit(elements, j2_secular=False).state(EPOCH)
    found = _elements(r, v)
    assert np.linalg.norm(r) == pytest.approx(EARTH_EQUATORIAL_RADIUS_M + 500e3, rel=1e-14)
    assert found["u"] == pytest.approx(2.0, abs=1e-12) and found["raan"] == pytest.approx(1.0, abs=1e-12)
    assert abs(r @ v) < 1e-6 * np.linalg.norm(r) * np.linalg.norm(v)


@pytest.mark.parametrize("elements", ELEMENTS, ids=["leo", "eccentric", "molniya"])
def test_two_body_motion_matches_numerical_integration_over_an_orbit(elements):
    orbit = KeplerianOrbit(elements, j2_secular=False)
    times = EPOCH + np.linspace(0.0, orbit.period_s, 80)
    r, v = orbit.state(times)
    r_ref, v_ref = _integrate(orbit, times)
    print(f"measured: two-body over an orbit {np.max(np.linalg.norm(r - r_ref, axis=1)):.2g} m, "
          f"{np.max(np.linalg.norm(v - v_ref, axis=1)):.2g} m/s from DOP853")
    assert np.max(np.linalg.norm(r - r_ref, axis=1)) < 1e-3  # [m]; 5e-5 measured
    assert np.max(np.linalg.norm(v - v_ref, axis=1)) < 1e-6  # [m/s]
    energy = np.sum(v * v, axis=1) / 2 - MU / np.linalg.norm(r, axis=1)
    assert np.allclose(energy, -MU / (2 * elements.semi_major_axis_m), rtol=1e-12, atol=0)
    assert np.linalg.norm(r[-1] - r[0]) < 1e-3 and np.linalg.norm(v[-1] - v[0]) < 1e-6  # closed after a period


@pytest.mark.parametrize("elements", [OrbitElements(7.2e6, 0.1, math.radians(30), 0.3, 1.0, 0.2, EPOCH),
                                      OrbitElements.circular(420e3, math.radians(51.6), 0.3, 0.7, EPOCH)],
                         ids=["eccentric", "iss-like"])
def test_j2_secular_drift_matches_integration_with_j2(elements):
    orbit = KeplerianOrbit(elements)
    times = EPOCH + np.linspace(0.0, 2 * 86400.0, 30001)
    first, last = times - times[0] < orbit.period_s, times[-1] - times < orbit.period_s
    node, perigee = _node_and_perigee(*_integrate(orbit, times, j2=True))
    model_node, model_perigee = _node_and_perigee(*orbit.state(times))

    def drift(angle):  # orbit-averaged, so that J2's short-period terms cancel
        return angle[last].mean() - angle[first].mean()
    print(f"measured: J2 node drift {drift(model_node) / drift(node) - 1:+.2%} from the integration with J2")
    assert drift(node) == pytest.approx(drift(model_node), rel=0.02)
    assert drift(model_node) == pytest.approx(orbit.raan_rate_rad_s * drift(times), rel=1e-3)
    if elements.eccentricity > 0:
        assert drift(perigee) == pytest.approx(drift(model_perigee), rel=0.02)


def test_velocity_is_the_derivative_of_position_with_the_drift():
    orbit = KeplerianOrbit(OrbitElements(7.2e6, 0.05, math.radians(98), 0.3, 1.0, 0.2, EPOCH))
    t = EPOCH + np.arange(0.0, 6000.0, 600.0)
    h = 0.5
    r = [orbit.state(t + k * h)[0] for k in (-2, -1, 1, 2)]
    derivative = (r[0] - 8 * r[1] + 8 * r[2] - r[3]) / (12 * h)
    assert np.max(np.linalg.norm(orbit.state(t)[1] - derivative, axis=1)) < 1e-5  # drift terms are ~1 m/s


def test_sun_synchronous_orbit_turns_with_the_mean_sun():
    # Published sun-synchronous inclinations (e.g. Wertz, Space Mission Analysis and Design).
    assert math.degrees(sun_synchronous_inclination(700e3)) == pytest.approx(98.19, abs=0.02)
    assert math.degrees(sun_synchronous_inclination(800e3)) == pytest.approx(98.60, abs=0.02)
    orbit = KeplerianOrbit(OrbitElements.circular(700e3, sun_synchronous_inclination(700e3), 0.5, 1.0, EPOCH))
    (t0, node0), (t1, node1) = (_ascending_node(orbit, EPOCH + days * 86400.0) for days in (0.0, 30.0))
    turned = math.remainder(node1 - node0, 2 * math.pi)
    assert turned / (t1 - t0) == pytest.approx(2 * math.pi / (365.2421897 * 86400.0), rel=1e-9)
    with pytest.raises(ValueError, match="altitude_m: no sun-synchronous orbit"):
        sun_synchronous_inclination(7000e3)


def test_states_follow_the_shape_of_the_times():
    orbit = KeplerianOrbit(ELEMENTS[1])
    r, v = orbit.state(EPOCH)
    assert r.shape == v.shape == (3,)
    r3, _ = orbit.state([EPOCH - 10.0, EPOCH, EPOCH + 10.0])
    assert r3.shape == (3, 3) and np.array_equal(r3[1], r)
    assert TleOrbit(*ISS).state(1.5759e9)[0].shape == (3,)


@pytest.mark.parametrize("lines", [ISS, VANGUARD, MOLNIYA], ids=["iss", "vanguard", "molniya"])
def test_tle_state_matches_sgp4_teme_rotated_by_astropy(lines):
    orbit = TleOrbit(*lines)
    unix = orbit.epoch_unix_s + np.linspace(-0.5, 2.0, 25) * 86400.0
    t = Time(unix, format="unix")
    errors, r_teme, v_teme = Satrec.twoline2rv(*lines).sgp4_array(t.utc.jd1, t.utc.jd2)
    assert not np.any(errors)
    with iers.conf.set_temp("auto_download", False):
        velocity = CartesianDifferential(v_teme.T * u.km / u.s)
        teme = TEME(CartesianRepresentation(r_teme.T * u.km, differentials=velocity), obstime=t)
        gcrs = teme.transform_to(GCRS(obstime=t))
    r, v = orbit.state(unix)
    print(f"measured: TLE {np.max(np.linalg.norm(r - gcrs.cartesian.xyz.to_value(u.m).T, axis=1)):.2g} m, "
          f"{np.max(np.linalg.norm(v - gcrs.velocity.d_xyz.to_value(u.m / u.s).T, axis=1)):.2g} m/s from astropy "
          f"TEME -> GCRS")
    assert np.max(np.linalg.norm(r - gcrs.cartesian.xyz.to_value(u.m).T, axis=1)) < 0.01
    assert np.max(np.linalg.norm(v - gcrs.velocity.d_xyz.to_value(u.m / u.s).T, axis=1)) < 1e-3
    # TEME and GCRS differ by the precession since 2000 and the nutation (17 arcsec): hundreds of metres.
    assert np.min(np.linalg.norm(r - r_teme * 1e3, axis=1)) > 100.0


def test_tle_epoch():
    assert TleOrbit(*ISS).epoch_unix_s == pytest.approx(Time("2019-12-09T16:38:29.363").unix, abs=1e-3)


def _with_checksum(line: str) -> str:
    total = sum(int(c) if c.isdigit() else c == "-" for c in line[:68])
    return line[:68] + str(total % 10)


@pytest.mark.parametrize("line1, line2, message", [
    (ISS[0][:-1] + "0", ISS[1], "line1: checksum"),
    (ISS[0], ISS[1][:-1] + "3", "line2: checksum"),
    (ISS[0][:60], ISS[1], "line1 must be a 69-character"),
    (ISS[1], ISS[0], "line1 must be a 69-character TLE line starting '1 '"),
    (ISS[0], _with_checksum(ISS[1].replace("0007417", "000741A")), "line2: the eccentricity"),
    (ISS[0], _with_checksum(ISS[1].replace("25544", "25545")), "different satellites"),
    (ISS[0], _with_checksum(ISS[1].replace("15.50103472", "00.00000000")), "SGP4 rejects the elements"),
    (None, ISS[1], "line1 must be a string"),
])
def test_bad_tles_are_refused_naming_the_line(line1, line2, message):
    with pytest.raises(ValueError, match=message):
        TleOrbit(line1, line2)


def test_tle_lines_may_carry_trailing_whitespace_and_a_decay_is_reported():
    assert validate_tle(ISS[0] + "  \n", ISS[1] + "\r\n") == ISS
    draggy = TleOrbit(_with_checksum(ISS[0].replace("38792-4", "99999-1")), ISS[1])
    with pytest.raises(ValueError, match="times: .*(below the Earth's surface|SGP4 fails)"):
        draggy.state(draggy.epoch_unix_s + np.array([0.0, 30 * 86400.0]))


@pytest.mark.parametrize("arguments, message", [
    ((7e6, -0.1, 0.5, 0, 0, 0, 0), "eccentricity must be in \\[0, 1\\)"),
    ((7e6, 1.0, 0.5, 0, 0, 0, 0), "eccentricity must be in \\[0, 1\\)"),
    ((7e6, 0.2, 0.5, 0, 0, 0, 0), "perigee at 5600000 m .* below its surface"),
    ((6.3e6, 0.0, 0.5, 0, 0, 0, 0), "below its surface"),
    ((-7e6, 0.0, 0.5, 0, 0, 0, 0), "semi_major_axis_m must be > 0"),
    ((7e6, 0.0, 4.0, 0, 0, 0, 0), "inclination_rad must be in \\[0, pi\\]"),
    ((7e6, 0.0, 0.5, float("nan"), 0, 0, 0), "raan_rad must be finite"),
    ((7e6, 0.0, 0.5, 0, 0, float("inf"), 0), "true_anomaly_rad must be finite"),
    ((7e6, 0.0, 0.5, 0, 0, 0, "soon"), "epoch_unix_s must be a number"),
])
def test_bad_elements_are_refused_naming_the_element(arguments, message):
    with pytest.raises(ValueError, match=message):
        OrbitElements(*arguments)


def test_bad_altitudes_and_times_are_refused():
    with pytest.raises(ValueError, match="altitude_m must be >= 0"):
        OrbitElements.circular(-1.0, 0.5)
    with pytest.raises(ValueError, match="times must be finite"):
        KeplerianOrbit(ELEMENTS[0]).state([EPOCH, np.nan])
    with pytest.raises(ValueError, match="elements must be OrbitElements"):
        KeplerianOrbit((7e6, 0.0, 0.5, 0, 0, 0, 0))
