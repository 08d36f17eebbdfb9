# SPDX-License-Identifier: Apache-2.0
"""
What an Environment puts in one frame: the head's geometry, planets, the Moon's disc and stray light.

Built once per frame at mid-exposure from the Environment (positions [m] and velocities
[m/s], GCRS) and the renderer's camera, sensor, attitude and EnvironmentModel; the renderer
adds the planets and the disc to its sky objects, hides what the Earth and the Moon cover,
and adds the stray-light plane to the static level.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..models.sky_geometry import HeadGeometry, earth_occults, head_geometry, unit
from .apparent_directions import apparent_directions
from .environment import Environment
from .moon_disc import DiscView, MoonDisc, moon_disc
from .stray_light import StrayPlane, stray_plane, stray_sources


class EnvironmentScene(NamedTuple):
    """
    One frame's environment.

    head: geometry and status at mid-exposure; planet_vectors (P, 3): apparent GCRS unit
    directions of the planets the Earth does not hide; planet_electrons (P,) [e-];
    moon: its disc or None; stray: the stray-light plane.
    """

    head: HeadGeometry
    planet_vectors: np.ndarray
    planet_electrons: np.ndarray
    moon: MoonDisc | None
    stray: StrayPlane


def environment_scene(view: DiscView, environment: Environment) -> EnvironmentScene:
    """Return what `environment` puts in the frame seen through `view` (camera, sensor, attitude, model)."""
    model = view.model
    head = head_geometry(view.rot_mid[:, 2], view.camera.half_diagonal_fov_rad, environment.bodies(),
                         model.exclusion)
    vectors, electrons = np.zeros((0, 3)), np.zeros(0)
    if model.planets and environment.planet_magnitudes.size:
        offsets = environment.planet_positions_m - environment.spacecraft_position_m
        vectors, electrons = unit(offsets), view.sensor.star_electrons(environment.planet_magnitudes)
        if model.earth_occultation:
            seen = ~earth_occults(vectors, environment.spacecraft_position_m, model.exclusion.limb_radius_m,
                                  np.linalg.norm(offsets, axis=1))
            vectors, electrons = vectors[seen], electrons[seen]
        if model.aberration:
            vectors = apparent_directions(vectors, environment.observer_velocity_m_s)
    moon = moon_disc(view, head, environment) if model.moon_disc else None
    sources = stray_sources(head, environment, model) if model.stray_light else (None, None, None)
    return EnvironmentScene(head, vectors, electrons, moon, stray_plane(sources, view.rot_mid, view.sensor, model))


def hidden_stars(scene: EnvironmentScene, directions: np.ndarray, environment: Environment,
                 view: DiscView) -> np.ndarray:
    """
    Return which geometric unit directions (N, 3) from the spacecraft the Earth (+ atmosphere) or the Moon's disc hide.

    Stars are at infinity: behind the Earth's occulting sphere when earth_occultation is on,
    within the Moon's angular radius of its centre when the disc is rendered.
    """
    hidden = np.zeros(directions.shape[0], bool)
    if view.model.earth_occultation:
        hidden |= earth_occults(directions, environment.spacecraft_position_m, view.model.exclusion.limb_radius_m)
    if scene.moon is not None:
        hidden |= directions @ scene.head.moon_direction > np.cos(scene.moon.radius_rad)
    return hidden
