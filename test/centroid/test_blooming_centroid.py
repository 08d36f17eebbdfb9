# SPDX-License-Identifier: Apache-2.0
"""
Saturated stars that bloom: their centroids stay within the covariance the centroider states.

Blooming (sim.blooming, on in every frame rendered with an environment) spills a clipped
pixel's excess along its column; the first pixel past each end of the clipped run holds
spilled charge that no PSF explains. With centroid.sensor_blooms the fit of a clipped
star leaves those pixels out with the clipped ones (detection/saturation.clipped_pixels).
Measured (pytest -s): 22 of these 48
stars clipped, chi^2 of the centroid errors mean 1.87, max 7.4; with the spill pixels fitted,
mean 958, max ~10^4 (a 0th-magnitude star moved along its column by up to ~0.05 px against a
stated ~0.0015 px, and outweighed every other star of an attitude fit).

Brighter stars (Hp -1.0 .. 0.5, Canopus is -0.7) bloom into footprints that run along their
columns; measured as streaks, 14 of 91 clipped ones got a covariance as wide as the footprint
(the streak fit failed), which in the stress campaign's task 737 (seed 2026) left the field's
brightest star out of 6 of 40 attitudes. With sensor_blooms such a footprint is a point
(frame_fits._routes): 0 of 91, chi^2 mean 1.59, max 7.2; on the second renderer (its own
blooming), 0 of 72 (38 before), chi^2 mean 1.81, max 14.4.
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from star_tracker.centroid import FLAG_SATURATED, CentroidConfig, extract_spots
from star_tracker.models.attitude import radec_roll_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.models.catalog import StarCatalog, unit_to_radec
from star_tracker.sim.environment import Environment
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import KIND_STAR, StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package

CAMERA = CameraModel.from_fov(1024, 1024, np.radians(15.0))
POINTING = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.0)


def bright_stars(rng: np.random.Generator) -> StarCatalog:
    """Sixteen stars of Hp -0.5 .. 1.5 on a grid at random sub-pixel phases."""
    cols, rows = np.meshgrid(np.arange(150, 1024 - 100, 220), np.arange(150, 1024 - 100, 220))
    x = cols.ravel() + rng.uniform(-0.5, 0.5, cols.size)
    y = rows.ravel() + rng.uniform(-0.5, 0.5, rows.size)
    ra, dec = unit_to_radec(CAMERA.pixel_to_ray(x, y) @ POINTING.T)
    n = x.size
    return StarCatalog(hip=np.arange(1, n + 1, dtype=np.int32), ra=ra, dec=dec, pm_ra=np.zeros(n),
                       pm_dec=np.zeros(n), hp=np.linspace(-0.5, 1.5, n), b_v=np.zeros(n), epoch_jyear=2026.0)


def test_blooming_stars_are_measured_within_their_stated_covariance():
    boresight = POINTING[:, 2]
    # The Earth, the Sun and the Moon behind the camera: the environment adds blooming alone.
    environment = Environment(spacecraft_position_m=7.0e6 * boresight, spacecraft_velocity_m_s=np.zeros(3),
                              sun_position_m=-1.5e11 * boresight, moon_position_m=-3.8e8 * boresight,
                              observer_velocity_m_s=np.zeros(3))
    chi2, saturated = [], 0
    for seed in range(3):
        renderer = StarFieldRenderer(CAMERA, SensorModel(), bright_stars(np.random.default_rng(seed)), 7.5)
        frame = renderer.render(ConstantRateMotion(POINTING, np.zeros(3)), 0.0, frame_seed(7, seed),
                                environment=environment)
        spots = extract_spots(frame.image, CentroidConfig(sensor_blooms=True))
        truth = frame.truth
        star = truth.kind == KIND_STAR
        for x, y in zip(truth.x[star], truth.y[star]):
            i = int(np.argmin(np.hypot(spots.x - x, spots.y - y)))
            error = np.array([spots.x[i] - x, spots.y[i] - y])
            assert np.hypot(*error) < 0.5
            chi2.append(float(error @ np.linalg.solve(spots.cov[i], error)))
            saturated += bool(spots.flags[i] & FLAG_SATURATED)
    print(f"\n{saturated} saturated of {len(chi2)}; chi2 mean {np.mean(chi2):.2f}, max {np.max(chi2):.1f}")
    assert saturated >= 15  # these stars bloom: the brighter ones are clipped
    assert np.mean(chi2) < 4.0 and np.max(chi2) < 25.0  # 2 DOF: mean 2


def _footprint_wide(spots, i: int) -> bool:
    """Whether spot i kept a covariance as wide as its footprint (no fit described it): sigma > 0.1 px."""
    return bool(np.sqrt(np.max(np.diagonal(spots.cov[i]))) > 0.1)


def _score(spots, x: np.ndarray, y: np.ndarray, chi2: list, saturated: int, wide: int) -> tuple[int, int]:
    """Append each true star's chi^2 (2 DOF) under its nearest spot's covariance; return the counts updated."""
    for tx, ty in zip(x, y):
        i = int(np.argmin(np.hypot(spots.x - tx, spots.y - ty)))
        error = np.array([spots.x[i] - tx, spots.y[i] - ty])
        chi2.append(float(error @ np.linalg.solve(spots.cov[i], error)))
        saturated += bool(spots.flags[i] & FLAG_SATURATED)
        wide += _footprint_wide(spots, i)
    return saturated, wide


def test_stars_elongated_by_their_bloom_are_fitted_as_points():
    boresight = POINTING[:, 2]
    environment = Environment(spacecraft_position_m=7.0e6 * boresight, spacecraft_velocity_m_s=np.zeros(3),
                              sun_position_m=-1.5e11 * boresight, moon_position_m=-3.8e8 * boresight,
                              observer_velocity_m_s=np.zeros(3))
    chi2, saturated, wide = [], 0, 0
    for seed in range(6):
        stars = bright_stars(np.random.default_rng(seed))
        stars = replace(stars, hp=np.linspace(-1.0, 0.5, stars.hp.size))
        frame = StarFieldRenderer(CAMERA, SensorModel(), stars, 7.5).render(
            ConstantRateMotion(POINTING, np.zeros(3)), 0.0, frame_seed(7, seed), environment=environment)
        spots = extract_spots(frame.image, CentroidConfig(sensor_blooms=True))
        star = frame.truth.kind == KIND_STAR
        saturated, wide = _score(spots, frame.truth.x[star], frame.truth.y[star], chi2, saturated, wide)
    print(f"\n{saturated} saturated of {len(chi2)}, {wide} footprint-wide; chi2 mean {np.mean(chi2):.2f}, "
          f"max {np.max(chi2):.1f}")
    assert saturated >= 80
    assert wide == 0
    assert np.mean(chi2) < 4.0 and np.max(chi2) < 25.0


def test_blooming_stars_of_the_second_renderer_are_fitted_within_their_covariance():
    """bench/alt_renderer.py's own blooming (Detector.blooms), every star of two frames clipped."""
    from bench import alt_renderer as alt

    rng = np.random.default_rng(5)
    chi2, saturated, wide = [], 0, 0
    for flux in (1.2e6, 2.0e6):
        cols, rows = np.meshgrid(np.arange(100, 1000, 150), np.arange(100, 1000, 150))
        x = cols.ravel() + rng.uniform(-0.5, 0.5, cols.size)
        y = rows.ravel() + rng.uniform(-0.5, 0.5, rows.size)
        frame = alt.render(alt.StarField.build(alt.GaussianPsf(1.0), x, y), flux, alt.Detector(blooms=True), 1024,
                           1024, rng)
        spots = extract_spots(frame.image, CentroidConfig(sensor_blooms=True))
        saturated, wide = _score(spots, x, y, chi2, saturated, wide)
    print(f"\n{saturated} saturated of {len(chi2)}, {wide} footprint-wide; chi2 mean {np.mean(chi2):.2f}, "
          f"max {np.max(chi2):.1f}")
    assert saturated == len(chi2)
    assert wide == 0
    assert np.mean(chi2) < 4.0 and np.max(chi2) < 25.0
