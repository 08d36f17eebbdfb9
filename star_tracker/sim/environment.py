# SPDX-License-Identifier: Apache-2.0
"""
The spacecraft's environment in one frame, and the parameters of what it does to the frame.

`Environment` is the per-frame input of StarFieldRenderer.render (positions from an
ephemeris and an orbit model, computed elsewhere); `EnvironmentModel` switches and tunes
each effect (Earth occultation, stray light and blinding, the Moon's disc, planets,
aberration, blooming), all on by default; `EnvironmentTruth` is what the frame's truth
says the environment did. Equations: docs/SIMULATOR.md, "The environment".
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..models.sky_geometry import BodyPositions, ExclusionModel, HeadGeometry
from ..parameter_spec import parameter, range_problems


def _vector(value, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=float)
    if array.shape != (3,) or not np.all(np.isfinite(array)):
        raise ValueError(f"{name}={value} must be 3 finite values")
    return array


@dataclass(frozen=True)
class Environment:
    """
    Where the spacecraft and the bright bodies are at a frame's mid-exposure (GCRS axes, SI units).

    spacecraft_position_m, spacecraft_velocity_m_s: geocentric [m, m/s]; sun_position_m,
    moon_position_m: geocentric [m]; observer_velocity_m_s: the observer's total velocity
    for aberration [m/s] (the Earth's barycentric plus the spacecraft's orbital);
    moon_illuminated_fraction [-]: the lit fraction of the Moon's disc (None: from the
    Sun-Moon-spacecraft angle); planet_positions_m (P, 3): geocentric [m];
    planet_magnitudes (P,): their visual magnitudes, taken as instrument magnitudes.
    """

    spacecraft_position_m: np.ndarray
    spacecraft_velocity_m_s: np.ndarray
    sun_position_m: np.ndarray
    moon_position_m: np.ndarray
    observer_velocity_m_s: np.ndarray
    moon_illuminated_fraction: float | None = None
    planet_positions_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    planet_magnitudes: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        for name in ("spacecraft_position_m", "spacecraft_velocity_m_s", "sun_position_m", "moon_position_m",
                     "observer_velocity_m_s"):
            object.__setattr__(self, name, _vector(getattr(self, name), name))
        planets = np.asarray(self.planet_positions_m, dtype=float).reshape(-1, 3)
        magnitudes = np.asarray(self.planet_magnitudes, dtype=float).reshape(-1)
        if planets.shape[0] != magnitudes.size or not (np.all(np.isfinite(planets))
                                                       and np.all(np.isfinite(magnitudes))):
            raise ValueError(f"{planets.shape[0]} planet positions and {magnitudes.size} magnitudes must match and "
                             "be finite")
        object.__setattr__(self, "planet_positions_m", planets)
        object.__setattr__(self, "planet_magnitudes", magnitudes)
        fraction = self.moon_illuminated_fraction
        if fraction is not None and not 0.0 <= fraction <= 1.0:
            raise ValueError(f"moon_illuminated_fraction={fraction} must be in [0, 1]")

    def bodies(self) -> BodyPositions:
        """Return the geocentric positions [m] sky_geometry works with."""
        return BodyPositions(self.spacecraft_position_m, self.sun_position_m, self.moon_position_m)


@dataclass(frozen=True)
class EnvironmentModel:
    """
    What an Environment does to a frame: each effect's switch and parameters (all on by default).

    Stray light: a source at angle theta [rad] from the boresight puts on each pixel
    N_src PST(theta) A_pix / A_ap electrons, N_src being the electrons the aperture would
    collect from it as a star (its magnitude through SensorModel.star_electrons), A_pix and
    A_ap the pixel's and the aperture's areas. PST = pst_at_exclusion (theta /
    theta_excl)^(-pst_exponent) from the source's exclusion angle theta_excl out to 90 deg
    (0 beyond: the source is behind the aperture's plane), pst_inside_exclusion inside it.
    The level varies linearly across the image, by +-stray_light_gradient of itself at the
    half diagonal, brighter toward the source. Sources whose total is below
    stray_light_floor_e at every pixel are left out. exclusion: the head's exclusion angles
    and the Earth's occulting sphere (models.sky_geometry).
    """

    earth_occultation: bool = parameter(True, "stars, planets and the Moon behind the Earth (+ atmosphere) are "
                                        "not rendered")
    stray_light: bool = parameter(True, "stray-light background from the Sun, the lit Earth and the Moon")
    moon_disc: bool = parameter(True, "the Moon as an extended, phased disc when in the field")
    planets: bool = parameter(True, "the Environment's planets as point sources")
    aberration: bool = parameter(True, "aberration with the Environment's observer velocity (off: geometric "
                                 "directions)")
    blooming: bool = parameter(True, "charge above the full well spills along its column (off: clipped)")
    earth_albedo: float = parameter(0.3, "the Earth's albedo for its reflected sunlight", "-", 0.0, 1.0)
    pst_at_exclusion: float = parameter(1e-6, "baffle point-source transmittance at a source's exclusion angle",
                                        "-", 0.0, 1.0)
    pst_exponent: float = parameter(8.0, "PST falls as (angle / exclusion angle) to minus this power", "-", 0.0,
                                    100.0)
    pst_inside_exclusion: float = parameter(1e-3, "PST inside a source's exclusion angle (the baffle lit "
                                            "directly)", "-", 0.0, 1.0)
    stray_light_gradient: float = parameter(0.5, "stray light's relative change from the image centre to the half "
                                            "diagonal toward the source", "-", 0.0, 1.0)
    stray_light_floor_e: float = parameter(0.5, "a source's stray light is left out below this at every pixel",
                                           "e-", 0.0, 1e9)
    exclusion: ExclusionModel = field(default_factory=ExclusionModel)

    def __post_init__(self) -> None:
        problems = range_problems(self)
        if problems:
            raise ValueError("invalid environment model: " + "; ".join(problems))


@dataclass(frozen=True)
class EnvironmentTruth:
    """
    What the environment did to one frame.

    head: the bodies' geometry and the head's status at mid-exposure; stray_light_e: the
    stray light of the Sun, the lit Earth and the Moon at the image centre [e- per pixel
    per exposure] (0 when left out); blinded: the stray light alone fills every pixel to
    the full well; moon_radius_px: the Moon's apparent radius at the local plate scale [px]
    (NaN when its disc is not rendered); occulted_hip: HIP numbers of the catalog stars near
    the field hidden by the Earth or the Moon.
    """

    head: HeadGeometry
    stray_light_e: tuple[float, float, float]
    blinded: bool
    moon_radius_px: float = math.nan
    occulted_hip: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
