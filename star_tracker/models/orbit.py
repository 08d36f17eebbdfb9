# SPDX-License-Identifier: Apache-2.0
"""
Spacecraft orbits: Keplerian elements (with the Earth's J2 secular drift) and two-line element sets (SGP4).

Every orbit has state(times) -> (r [m], v [m/s]): the spacecraft's geocentric position and
velocity on GCRS axes (ICRS-aligned), at UNIX times [s] (UTC, as ROS stamps); a scalar time gives
(3,) vectors, an array of K times (K, 3). v is the time derivative of r.

KeplerianOrbit treats its elements as mean elements. With j2_secular (the default) the node, the
argument of perigee and the mean anomaly drift at the Earth's J2 first-order secular rates
(Brouwer; e.g. Vallado, Fundamentals of Astrodynamics, 4th ed., sec. 9.6), so that a sun-synchronous
orbit keeps its local time over days and weeks; J2's short-period terms (~10 km in low orbit),
drag, the Moon, the Sun and the other harmonics are left out. Without j2_secular it is two-body
motion. TleOrbit propagates a TLE with SGP4 (the sgp4 package through skyfield's EarthSatellite,
TEME rotated to GCRS by skyfield's IAU 2006/2000A precession-nutation); its accuracy is the TLE's:
~1 km at epoch, growing a few km a day.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

EARTH_MU_M3_S2 = 3.986004418e14  # GM of the Earth with its atmosphere (WGS 84, EGM96)
EARTH_EQUATORIAL_RADIUS_M = 6_378_137.0  # WGS 84
EARTH_POLAR_RADIUS_M = 6_356_752.314  # WGS 84
EARTH_J2 = 1.08262668e-3  # EGM96 (-C20, unnormalized)
TROPICAL_YEAR_S = 365.2421897 * 86400.0
# A sun-synchronous orbit's node follows the mean Sun: one turn eastward per tropical year.
SUN_SYNCHRONOUS_RAAN_RATE_RAD_S = 2.0 * math.pi / TROPICAL_YEAR_S
_KEPLER_TOLERANCE_RAD = 1e-14
_KEPLER_MAX_STEPS = 50


def _finite(value, name: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    return x


def _times(times) -> np.ndarray:
    t = np.asarray(times, dtype=float)
    if not np.all(np.isfinite(t)):
        raise ValueError(f"times must be finite UNIX seconds, got {times!r}")
    return t


@dataclass(frozen=True)
class OrbitElements:
    """
    Classical orbital elements at an epoch, GCRS axes (the equator and equinox are ICRS-aligned).

    semi_major_axis_m [m]; eccentricity in [0, 1); inclination_rad in [0, pi]; raan_rad (right
    ascension of the ascending node), arg_perigee_rad, true_anomaly_rad [rad], any finite value;
    epoch_unix_s: UNIX time [s] at which the anomaly holds. The perigee must clear the Earth's
    equatorial radius. For a circular orbit the argument of perigee and the true anomaly only
    count through their sum (the argument of latitude): see circular().
    """

    semi_major_axis_m: float
    eccentricity: float
    inclination_rad: float
    raan_rad: float
    arg_perigee_rad: float
    true_anomaly_rad: float
    epoch_unix_s: float

    def __post_init__(self) -> None:
        for name in ("semi_major_axis_m", "eccentricity", "inclination_rad", "raan_rad", "arg_perigee_rad",
                     "true_anomaly_rad", "epoch_unix_s"):
            object.__setattr__(self, name, _finite(getattr(self, name), name))
        if not 0.0 <= self.eccentricity < 1.0:
            raise ValueError(f"eccentricity must be in [0, 1) (a closed orbit), got {self.eccentricity}")
        if not 0.0 <= self.inclination_rad <= math.pi:
            raise ValueError(f"inclination_rad must be in [0, pi], got {self.inclination_rad}")
        if self.semi_major_axis_m <= 0:
            raise ValueError(f"semi_major_axis_m must be > 0, got {self.semi_major_axis_m}")
        if self.perigee_radius_m < EARTH_EQUATORIAL_RADIUS_M:
            raise ValueError(f"semi_major_axis_m and eccentricity put the perigee at {self.perigee_radius_m:.0f} m "
                             f"from the Earth's centre, below its surface (equatorial radius "
                             f"{EARTH_EQUATORIAL_RADIUS_M:.0f} m)")

    @classmethod
    def circular(cls, altitude_m: float, inclination_rad: float, raan_rad: float = 0.0, arg_latitude_rad: float = 0.0,
                 epoch_unix_s: float = 0.0) -> "OrbitElements":
        """Circular orbit altitude_m [m] above the equatorial radius; arg_latitude_rad: angle from the node [rad]."""
        altitude = _finite(altitude_m, "altitude_m")
        if altitude < 0:
            raise ValueError(f"altitude_m must be >= 0 (above the Earth's surface), got {altitude}")
        return cls(EARTH_EQUATORIAL_RADIUS_M + altitude, 0.0, inclination_rad, raan_rad, 0.0, arg_latitude_rad,
                   epoch_unix_s)

    @property
    def perigee_radius_m(self) -> float:
        return self.semi_major_axis_m * (1.0 - self.eccentricity)

    @property
    def apogee_radius_m(self) -> float:
        return self.semi_major_axis_m * (1.0 + self.eccentricity)


def _j2_factor(semi_major_axis_m: float, eccentricity: float) -> tuple[float, float]:
    """Mean motion n [rad/s] and 1.5 n J2 (R / p)^2 [rad/s], the scale of the J2 secular rates."""
    n = math.sqrt(EARTH_MU_M3_S2 / semi_major_axis_m**3)
    p = semi_major_axis_m * (1.0 - eccentricity**2)
    return n, 1.5 * n * EARTH_J2 * (EARTH_EQUATORIAL_RADIUS_M / p) ** 2


def sun_synchronous_inclination(altitude_m: float, eccentricity: float = 0.0) -> float:
    """
    Inclination [rad] whose J2 nodal drift follows the mean Sun, at a mean altitude_m [m] (a = R_eq + altitude).

    cos i = -(2 pi / tropical year) / (1.5 n J2 (R_eq / p)^2); ~98.2 deg at 700 km. Raises ValueError
    above ~5970 km, where J2 cannot turn the node fast enough.
    """
    altitude = _finite(altitude_m, "altitude_m")
    a = EARTH_EQUATORIAL_RADIUS_M + altitude
    elements = OrbitElements(a, eccentricity, 0.0, 0.0, 0.0, 0.0, 0.0)  # validates altitude and eccentricity
    _, k = _j2_factor(elements.semi_major_axis_m, elements.eccentricity)
    cos_i = -SUN_SYNCHRONOUS_RAAN_RATE_RAD_S / k
    if cos_i < -1.0:
        raise ValueError(f"altitude_m: no sun-synchronous orbit at {altitude:.0f} m (J2 turns the node too slowly)")
    return math.acos(cos_i)


def solve_kepler(mean_anomaly_rad: np.ndarray, eccentricity: float) -> np.ndarray:
    """Eccentric anomaly E [rad] with E - e sin E = M (Newton's method, to 1e-14 rad), elementwise."""
    m = np.asarray(mean_anomaly_rad, dtype=float)
    e = float(eccentricity)
    m_wrapped = np.remainder(m + np.pi, 2 * np.pi) - np.pi  # in [-pi, pi): Newton from a good start
    # Start points from which Newton converges for every M (Vallado, algorithm 2).
    ecc = m_wrapped + e * np.sin(m_wrapped) if e < 0.8 else np.pi * np.sign(m_wrapped)
    for _ in range(_KEPLER_MAX_STEPS):
        step = (ecc - e * np.sin(ecc) - m_wrapped) / (1.0 - e * np.cos(ecc))
        ecc = ecc - step
        if np.all(np.abs(step) < _KEPLER_TOLERANCE_RAD):
            break
    return ecc + (m - m_wrapped)


class KeplerianOrbit:
    """
    An orbit from OrbitElements, optionally with the J2 secular drift (see the module docstring).

    Rates [rad/s]: mean_motion_rad_s (two-body n), raan_rate_rad_s, arg_perigee_rate_rad_s,
    mean_anomaly_rate_rad_s (n plus J2's term); period_s = 2 pi / mean_anomaly_rate_rad_s (the
    anomalistic period) [s].
    """

    def __init__(self, elements: OrbitElements, j2_secular: bool = True) -> None:
        if not isinstance(elements, OrbitElements):
            raise ValueError(f"elements must be OrbitElements, got {type(elements).__name__}")
        self.elements = elements
        self.j2_secular = bool(j2_secular)
        a, e, i = elements.semi_major_axis_m, elements.eccentricity, elements.inclination_rad
        n, k = _j2_factor(a, e)
        if not self.j2_secular:
            k = 0.0
        sin2 = math.sin(i) ** 2
        self.mean_motion_rad_s = n
        self.raan_rate_rad_s = -k * math.cos(i)
        self.arg_perigee_rate_rad_s = k * (2.0 - 2.5 * sin2)
        self.mean_anomaly_rate_rad_s = n + k * math.sqrt(1.0 - e * e) * (1.0 - 1.5 * sin2)
        self.period_s = 2.0 * math.pi / self.mean_anomaly_rate_rad_s
        nu = elements.true_anomaly_rad
        ecc_anomaly = 2.0 * math.atan2(math.sqrt(1.0 - e) * math.sin(nu / 2), math.sqrt(1.0 + e) * math.cos(nu / 2))
        self._mean_anomaly_at_epoch = ecc_anomaly - e * math.sin(ecc_anomaly)

    def __repr__(self) -> str:
        return f"KeplerianOrbit({self.elements!r}, j2_secular={self.j2_secular})"

    def state(self, times) -> tuple[np.ndarray, np.ndarray]:
        """Position [m] and velocity [m/s] on GCRS axes at UNIX times [s]: (3,) each, or (K, 3) for K times."""
        t = _times(times)
        el = self.elements
        a, e = el.semi_major_axis_m, el.eccentricity
        dt = t.reshape(-1) - el.epoch_unix_s
        ecc = solve_kepler(self._mean_anomaly_at_epoch + self.mean_anomaly_rate_rad_s * dt, e)
        cos_e, sin_e = np.cos(ecc), np.sin(ecc)
        root = math.sqrt(1.0 - e * e)
        e_dot = self.mean_anomaly_rate_rad_s / (1.0 - e * cos_e)  # dE/dt from Kepler's equation
        x, y = a * (cos_e - e), a * root * sin_e  # perifocal coordinates
        vx, vy = -a * sin_e * e_dot, a * root * cos_e * e_dot
        p_hat, q_hat, h_hat = _perifocal_axes(el.raan_rad + self.raan_rate_rad_s * dt, el.inclination_rad,
                                              el.arg_perigee_rad + self.arg_perigee_rate_rad_s * dt)
        r = x[:, None] * p_hat + y[:, None] * q_hat
        # The drifting node and perigee turn the orbit: about the pole (RAAN) and the orbit normal (perigee).
        v = (vx[:, None] * p_hat + vy[:, None] * q_hat + self.raan_rate_rad_s * np.cross([0.0, 0.0, 1.0], r)
             + self.arg_perigee_rate_rad_s * np.cross(h_hat, r))
        shape = t.shape + (3,)
        return r.reshape(shape), v.reshape(shape)


def _perifocal_axes(raan: np.ndarray, inclination: float, arg_perigee: np.ndarray) -> tuple[np.ndarray, ...]:
    """GCRS unit vectors (K, 3) to the perigee, 90 deg ahead of it in the orbit plane, and along the orbit normal."""
    cos_o, sin_o = np.cos(raan), np.sin(raan)
    cos_w, sin_w = np.cos(arg_perigee), np.sin(arg_perigee)
    cos_i, sin_i = math.cos(inclination), math.sin(inclination)
    p_hat = np.stack([cos_o * cos_w - sin_o * sin_w * cos_i, sin_o * cos_w + cos_o * sin_w * cos_i,
                      sin_w * sin_i], axis=-1)
    q_hat = np.stack([-cos_o * sin_w - sin_o * cos_w * cos_i, -sin_o * sin_w + cos_o * cos_w * cos_i,
                      cos_w * sin_i], axis=-1)
    h_hat = np.stack([sin_o * sin_i, -cos_o * sin_i, np.full_like(cos_o, cos_i)], axis=-1)
    return p_hat, q_hat, h_hat


def _tle_checksum(line: str) -> int:
    return sum(int(c) if c.isdigit() else (1 if c == "-" else 0) for c in line[:68]) % 10


# Numeric fields (0-based column slices) that SGP4 would otherwise read as 0 when garbled.
_TLE_FIELDS = {"line1": (("epoch", slice(18, 32)),),
               "line2": (("inclination", slice(8, 16)), ("right ascension of the node", slice(17, 25)),
                         ("eccentricity", slice(26, 33)), ("argument of perigee", slice(34, 42)),
                         ("mean anomaly", slice(43, 51)), ("mean motion", slice(52, 63)))}


def validate_tle(line1: str, line2: str) -> tuple[str, str]:
    """
    Return the two TLE lines (trailing whitespace dropped) after checking their format.

    Each line is 69 characters, starts "1 " / "2 ", ends with its modulo-10 checksum (digits, '-'
    counts 1), has numbers in its element fields, and both carry the same catalog number. Raises
    ValueError naming line1 or line2.
    """
    lines = {}
    for name, line, number in (("line1", line1, "1"), ("line2", line2, "2")):
        if not isinstance(line, str):
            raise ValueError(f"{name} must be a string, got {type(line).__name__}")
        line = line.rstrip()
        if len(line) != 69 or line[:2] != f"{number} ":
            raise ValueError(f"{name} must be a 69-character TLE line starting '{number} ', got {line!r}")
        if not line[68].isdigit() or int(line[68]) != _tle_checksum(line):
            raise ValueError(f"{name}: checksum {line[68]!r} does not match the line (expected {_tle_checksum(line)})")
        for field, columns in _TLE_FIELDS[name]:
            text = line[columns].strip()
            if not (text.replace(".", "", 1).isdigit()):
                raise ValueError(f"{name}: the {field} (columns {columns.start + 1}-{columns.stop}) must be a number, "
                                 f"got {line[columns]!r}")
        lines[name] = line
    if lines["line1"][2:7] != lines["line2"][2:7]:
        raise ValueError(f"line1 and line2 are for different satellites ({lines['line1'][2:7]!r} and "
                         f"{lines['line2'][2:7]!r})")
    return lines["line1"], lines["line2"]


class TleOrbit:
    """
    An orbit from a two-line element set, propagated with SGP4 and rotated from TEME to GCRS.

    line1, line2: the TLE's lines (validated: validate_tle). epoch_unix_s: the TLE's epoch [s].
    state raises ValueError at times where SGP4 fails or puts the satellite below the Earth's polar
    radius (it has decayed). No limit on the age of the TLE: its error grows by km a day.
    """

    def __init__(self, line1: str, line2: str) -> None:
        from sgp4.api import SGP4_ERRORS
        from skyfield.api import EarthSatellite

        from .ephemeris import timescale
        self.line1, self.line2 = validate_tle(line1, line2)
        try:
            self._satellite = EarthSatellite(self.line1, self.line2, ts=timescale())
        except (ValueError, IndexError) as error:
            raise ValueError(f"line1/line2: SGP4 cannot read the TLE: {error}") from None
        if self._satellite.model.error:
            raise ValueError(f"line1/line2: SGP4 rejects the elements: {SGP4_ERRORS[self._satellite.model.error]}")
        self.epoch_unix_s = float(self._satellite.epoch.utc_datetime().timestamp())

    def __repr__(self) -> str:
        return f"TleOrbit({self.line1!r}, {self.line2!r})"

    def state(self, times) -> tuple[np.ndarray, np.ndarray]:
        """Position [m] and velocity [m/s] on GCRS axes at UNIX times [s]: (3,) each, or (K, 3) for K times."""
        from .ephemeris import skyfield_time

        t = _times(times)
        position = self._satellite.at(skyfield_time(t))
        r = np.moveaxis(position.position.m, 0, -1)
        v = np.moveaxis(position.velocity.m_per_s, 0, -1)
        failed = ~np.isfinite(np.concatenate([r, v], axis=-1)).all(axis=-1).reshape(-1)
        if np.any(failed):
            messages = position.message if isinstance(position.message, list) else [position.message]
            raise ValueError(f"times: SGP4 fails at {t.reshape(-1)[np.argmax(failed)]:.3f} s (UNIX), "
                             f"{(t.reshape(-1)[np.argmax(failed)] - self.epoch_unix_s) / 86400.0:.2f} days from the "
                             f"TLE epoch: {'; '.join(sorted({m for m in messages if m}))}")
        below = np.linalg.norm(r, axis=-1).reshape(-1) < EARTH_POLAR_RADIUS_M
        if np.any(below):
            raise ValueError(f"times: at {t.reshape(-1)[np.argmax(below)]:.3f} s (UNIX) SGP4 puts the satellite below "
                             f"the Earth's surface (it has decayed by then)")
        return r, v
