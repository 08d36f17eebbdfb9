# SPDX-License-Identifier: Apache-2.0
"""
Simulated scenes more than one benchmark renders.

CAMERA and POINTING: the 1024² 15° camera and the fixed pointing of the centroiding benchmarks;
grid_scene: a catalog of equal stars on a pixel grid seen from there (bench_centroid,
bench_psf_range); static_level: the sky and dark electrons a pixel collects in one exposure;
random_rotation: an attitude uniform over SO(3) (bench_attitude, bench_rate_aid).
"""
from __future__ import annotations

import numpy as np

from star_tracker.models.attitude import quaternion_to_matrix, radec_roll_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.models.catalog import StarCatalog, unit_to_radec
from star_tracker.sim.sensor import SensorModel

CAMERA = CameraModel.from_fov(1024, 1024, np.radians(15.0))
POINTING = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.0)


def grid_scene(sensor: SensorModel, flux_e: float, rng: np.random.Generator, spacing: int = 110):
    """Return a catalog of stars on a pixel grid (random sub-pixel phase) of flux `flux_e` [e-]."""
    cols, rows = np.meshgrid(np.arange(80, 1024 - 80, spacing), np.arange(80, 1024 - 80, spacing))
    x = cols.ravel() + rng.uniform(-0.5, 0.5, cols.size)
    y = rows.ravel() + rng.uniform(-0.5, 0.5, rows.size)
    ra, dec = unit_to_radec(CAMERA.pixel_to_ray(x, y) @ POINTING.T)
    hp = -2.5 * np.log10(flux_e / (sensor.zero_point_e_per_s * sensor.exposure_s))
    n = x.size
    return StarCatalog(hip=np.arange(1, n + 1, dtype=np.int32), ra=ra, dec=dec, pm_ra=np.zeros(n), pm_dec=np.zeros(n),
                       hp=np.full(n, hp), b_v=np.zeros(n), epoch_jyear=2026.0)


def static_level(sensor: SensorModel) -> float:
    """Sky background plus dark current per pixel in one exposure [e-]."""
    return (sensor.background_e_per_px_s + sensor.dark_e_per_px_s_at_temperature) * sensor.exposure_s


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniform over SO(3): a normalized 4-D Gaussian quaternion."""
    return quaternion_to_matrix(rng.normal(size=4))
