# SPDX-License-Identifier: Apache-2.0
"""
Sun, Moon and planets seen from the Earth: JPL DE421 as shipped by the skyfield-data package.

Positions are geocentric and astrometric: the vector [m] from the Earth's centre at time t to the
body where it was when the light now arriving left it (light-time corrected), on GCRS axes (ICRS
axes, no rotation between them). They carry neither aberration nor light deflection: the observer
applies aberration with its own total velocity (models/aberration.py: the Earth's barycentric
velocity, earth_velocity(), plus its orbital velocity), so adding it here would count it twice.
For an observer at p (GCRS [m]) pass observer_m=p: the vector becomes body - p (parallax: ~1 deg for
the Moon from low Earth orbit). The light time is the Earth centre's; from orbit it differs by
< 25 ms, < 30 m of the Moon's motion.

Times are UNIX seconds (UTC, float, as ROS stamps), converted to TT inside with skyfield's built-in
leap-second table. Every time-dependent method takes a scalar or an array of times and returns
shape np.shape(times) + (3,) for vectors, np.shape(times) for scalars. Outside the file's span
(1899-07-30 .. 2053-10-07 UTC: DE421's own limits less a day for the light time, rounded inward
to whole days) a ValueError names the span. Nothing is downloaded: the kernel and the timescale
come from installed packages.

Jupiter and Saturn are their system barycentres (DE421 has no planet-centre segments for them:
< 1000 km off the planet, < 0.1 arcsec at their distances). Use load_ephemeris() for the shared,
lazily loaded instance (a module-level cache, so importing this module reads no file).
"""
from __future__ import annotations

import threading
import warnings
from pathlib import Path

import numpy as np

SUN_RADIUS_M = 6.957e8  # IAU 2015 Resolution B3 nominal solar radius
MOON_RADIUS_M = 1.7374e6  # mean radius (IAU WGCCRE)
EPHEMERIS_FILE = "de421.bsp"
PLANETS = ("mercury", "venus", "mars", "jupiter", "saturn")
BODIES = ("sun", "moon") + PLANETS
_SEGMENT_TARGETS = {"sun": "sun", "moon": "moon", "mercury": "mercury", "venus": "venus", "mars": "mars",
                    "jupiter": "jupiter barycenter", "saturn": "saturn barycenter"}
# Kept inside the kernel's span so that the light-time iteration (Saturn's light takes ~1.5 h)
# never asks the kernel for a time beyond its end.
_SPAN_MARGIN_DAYS = 1.0
_SECONDS_PER_DAY = 86400.0

_LOCK = threading.RLock()  # re-entered: load_ephemeris -> Ephemeris() -> timescale()
_CACHE: dict = {}


def shipped_data_path() -> Path:
    """
    Return the folder of the files skyfield-data ships (de421.bsp among them).

    skyfield-data warns that its Earth-orientation file (finals2000A.all) has expired; nothing here
    reads that file (the timescale is skyfield's built-in one), so the warning is silenced.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*has expired.*", category=RuntimeWarning)
        import skyfield_data
        return Path(skyfield_data.get_skyfield_data_path())


def timescale():
    """Return skyfield's built-in time scale, with the leap seconds and Delta T it ships; loaded once."""
    with _LOCK:
        if "timescale" not in _CACHE:
            from skyfield.api import load
            _CACHE["timescale"] = load.timescale(builtin=True)
        return _CACHE["timescale"]


def skyfield_time(times):
    """
    Convert UNIX seconds (UTC) to a skyfield Time (scalar or array, as given).

    UNIX time counts 86400 s a day and skips leap seconds: whole days from 1970-01-01 plus the
    second of the day are passed as a UTC calendar date, so skyfield applies the leap seconds.
    """
    t = np.asarray(times, dtype=float)
    if not np.all(np.isfinite(t)):
        raise ValueError(f"times must be finite UNIX seconds, got {times!r}")
    days = np.floor(t / _SECONDS_PER_DAY)
    return timescale().utc(1970, 1, 1 + days, 0, 0, t - days * _SECONDS_PER_DAY)


def load_ephemeris() -> "Ephemeris":
    """Return the shared Ephemeris of the shipped DE421, loaded on the first call."""
    with _LOCK:
        if "ephemeris" not in _CACHE:
            _CACHE["ephemeris"] = Ephemeris()
    return _CACHE["ephemeris"]


def _angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors along the last axis [rad], accurate at 0 and pi."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


class Ephemeris:
    """
    Geocentric astrometric positions of the Sun, Moon and planets from a JPL kernel (see the module docstring).

    path: a .bsp file; None (the default) loads the DE421 that skyfield-data ships. Loading takes
    ~40 ms; the kernel is memory-mapped. Thread-safe for reading (no mutable state after loading).
    """

    def __init__(self, path: str | Path | None = None) -> None:
        from skyfield.api import Loader

        file = Path(path) if path is not None else shipped_data_path() / EPHEMERIS_FILE
        if not file.is_file():
            raise ValueError(f"path: no ephemeris file at {file}")
        self._kernel = Loader(str(file.parent), expire=False, verbose=False)(file.name)
        self._earth = self._kernel["earth"]
        self._bodies = {name: self._kernel[target] for name, target in _SEGMENT_TARGETS.items()}
        # The kernel's span (TDB in the file; TT is < 2 ms off) less the light-time margin, rounded
        # inward to whole UTC days so that it reads as dates.
        segments = self._kernel.spk.segments
        first_tt = max(segment.start_jd for segment in segments) + _SPAN_MARGIN_DAYS
        last_tt = min(segment.end_jd for segment in segments) - _SPAN_MARGIN_DAYS
        start, end = (timescale().tt_jd(jd).utc_datetime().timestamp() / _SECONDS_PER_DAY for jd in (first_tt, last_tt))
        self.span_unix_s = (float(np.ceil(start)) * _SECONDS_PER_DAY, float(np.floor(end)) * _SECONDS_PER_DAY)
        self.span_utc = tuple(_utc_datetime(x).strftime("%Y-%m-%d") for x in self.span_unix_s)

    # ------------------------------------------------------------ time
    def _time(self, times):
        """Skyfield Time of UNIX seconds, after checking them against the span."""
        t = np.asarray(times, dtype=float).reshape(-1)
        outside = (t < self.span_unix_s[0]) | (t > self.span_unix_s[1])
        if np.any(outside):
            (first, last), (first_s, last_s) = self.span_utc, self.span_unix_s
            raise ValueError(f"times: {t[np.argmax(outside)]} s (UNIX) is outside the ephemeris span {first} .. {last}"
                             f" UTC (UNIX {first_s:.0f} .. {last_s:.0f} s)")
        return skyfield_time(times)

    def _observe(self, body: str, times):
        if body not in self._bodies:
            raise ValueError(f"body must be one of {BODIES}, got {body!r}")
        return self._earth.at(self._time(times)).observe(self._bodies[body])

    # ------------------------------------------------------------ vectors
    def position(self, body: str, times, observer_m=None) -> np.ndarray:
        """
        Astrometric GCRS vector [m] from the observer to body ("sun", "moon", or one of PLANETS).

        observer_m: the observer's GCRS position [m], (3,) or broadcastable to the result; None: the
        Earth's centre. Shape np.shape(times) + (3,).
        """
        vector = np.moveaxis(self._observe(body, times).position.m, 0, -1)
        return vector if observer_m is None else vector - _observer(observer_m)

    def sun_position(self, times, observer_m=None) -> np.ndarray:
        """Astrometric GCRS vector [m] to the Sun (see position)."""
        return self.position("sun", times, observer_m)

    def moon_position(self, times, observer_m=None) -> np.ndarray:
        """Astrometric GCRS vector [m] to the Moon (see position)."""
        return self.position("moon", times, observer_m)

    def earth_velocity(self, times) -> np.ndarray:
        """Barycentric velocity of the Earth's centre [m/s] on ICRS axes, shape np.shape(times) + (3,)."""
        return np.moveaxis(self._earth.at(self._time(times)).velocity.m_per_s, 0, -1)

    # ------------------------------------------------------------ photometry and sizes
    def planet_magnitude(self, body: str, times) -> np.ndarray:
        """
        Apparent visual magnitude V of a planet (one of PLANETS) seen from the Earth's centre.

        Mallama & Hilton (2018), the Astronomical Almanac's formulas, via skyfield's
        magnitudelib.planetary_magnitude: Saturn includes its rings; Mars omits the +-0.06 mag of
        its rotation. From low Earth orbit the distance changes it by < 0.001 mag. Shape np.shape(times).
        """
        if body not in PLANETS:
            raise ValueError(f"body must be one of {PLANETS}, got {body!r}")
        from skyfield.magnitudelib import planetary_magnitude
        return np.asarray(planetary_magnitude(self._observe(body, times)), dtype=float)

    def moon_illuminated_fraction(self, times, observer_m=None) -> np.ndarray:
        """
        Illuminated fraction of the Moon's disc, (1 + cos(phase angle)) / 2, in [0, 1].

        The phase angle is the angle Sun-Moon-observer; observer_m as in position (None: the Earth's
        centre). Shape np.shape(times).
        """
        moon = self.moon_position(times, observer_m)
        sun = self.sun_position(times, observer_m)
        return 0.5 * (1.0 + np.cos(_angle_between(sun - moon, -moon)))

    def moon_angular_radius(self, times, observer_m=None) -> np.ndarray:
        """Apparent angular radius of the Moon [rad] (mean radius MOON_RADIUS_M); observer_m as in position."""
        return np.arcsin(MOON_RADIUS_M / np.linalg.norm(self.moon_position(times, observer_m), axis=-1))

    def sun_angular_radius(self, times, observer_m=None) -> np.ndarray:
        """Apparent angular radius of the Sun [rad] (nominal radius SUN_RADIUS_M); observer_m as in position."""
        return np.arcsin(SUN_RADIUS_M / np.linalg.norm(self.sun_position(times, observer_m), axis=-1))


def _utc_datetime(unix_s: float):
    import datetime
    return datetime.datetime.fromtimestamp(unix_s, tz=datetime.timezone.utc)


def _observer(observer_m) -> np.ndarray:
    p = np.asarray(observer_m, dtype=float)
    if p.ndim == 0 or p.shape[-1] != 3 or not np.all(np.isfinite(p)):
        raise ValueError(f"observer_m must be finite GCRS positions [m] of shape (..., 3), got {observer_m!r}")
    return p
