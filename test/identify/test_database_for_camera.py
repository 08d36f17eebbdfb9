# SPDX-License-Identifier: Apache-2.0
"""
DatabaseConfig.for_camera.

The pair-angle limit derived from a camera model covers its field, and the database it gives
solves that camera's scenes (against simulator truth).
"""
import math

import numpy as np
import pytest

from star_tracker.identify import DatabaseConfig, load_or_build_database, make_identifier
from star_tracker.models.camera import CameraModel
from star_tracker.sim.scenes import SETUPS, SceneSetup, make_scene

WIDE = CameraModel.from_fov(1024, 1024, math.radians(20.0))  # 28.1 deg diagonal: beyond the default 22 deg


def widest_angle_on_the_border(camera: CameraModel, samples: int = 200) -> float:
    """Return the largest angle between two points of the image border (pixel edges), brute force [rad]."""
    t = np.linspace(0.0, 1.0, samples)
    w, h = camera.width - 0.5, camera.height - 0.5
    u = np.concatenate([-0.5 + t * camera.width, np.full(samples, w), -0.5 + t * camera.width, np.full(samples, -0.5)])
    v = np.concatenate([np.full(samples, -0.5), -0.5 + t * camera.height, np.full(samples, h),
                        -0.5 + t * camera.height])
    rays = camera.pixel_to_ray(u, v)
    return float(np.arccos(np.clip(rays @ rays.T, -1.0, 1.0)).max())


@pytest.mark.parametrize("camera", [
    CameraModel.from_fov(1024, 1024, math.radians(15.0)),
    WIDE,
    CameraModel.from_fov(2048, 1536, math.radians(40.0)),
    CameraModel(1280, 720, 900.0, 905.0, 700.0, 300.0),  # principal point far off centre
    CameraModel.from_fov(1024, 1024, math.radians(30.0), (-0.2, 0.05, 0.0, 0.0, 0.0)),  # barrel distortion
], ids=["15deg", "20deg", "40deg_4x3", "off_centre", "distorted"])
def test_pair_angle_limit_covers_the_field_diagonal(camera):
    config = DatabaseConfig.for_camera(camera)
    diagonal = widest_angle_on_the_border(camera)
    assert config.max_pair_angle_rad >= diagonal
    if diagonal <= DatabaseConfig().max_pair_angle_rad:  # fits the default: shares its database and cache file
        assert config == DatabaseConfig()
    else:  # the diagonal + 1 deg, a whole number of degrees: no wider than needed
        assert diagonal + math.radians(1.0) <= config.max_pair_angle_rad < diagonal + math.radians(2.0) + 1e-12
        assert math.degrees(config.max_pair_angle_rad) == pytest.approx(round(math.degrees(config.max_pair_angle_rad)))


def test_magnitude_and_epoch_are_kept_and_a_too_wide_field_is_refused():
    config = DatabaseConfig.for_camera(WIDE, magnitude_limit=5.5, epoch_jyear=2030.0)
    assert (config.magnitude_limit, config.epoch_jyear) == (5.5, 2030.0)
    assert DatabaseConfig.for_camera(WIDE).magnitude_limit == DatabaseConfig().magnitude_limit
    with pytest.raises(ValueError, match="field diagonal"):
        DatabaseConfig.for_camera(CameraModel.from_fov(1024, 1024, math.radians(100.0)))


def test_its_database_solves_the_cameras_scenes_and_holds_every_pair_in_view(catalog):
    database = load_or_build_database(DatabaseConfig.for_camera(WIDE))
    setup = SceneSetup("wide", WIDE, None, 6.5, 0.2 * WIDE.pixel_scale_rad, 0.1)
    sky = catalog.at_epoch(2026.0)
    identifier = make_identifier("hybrid", database)
    if hasattr(identifier, "warm_up"):
        identifier.warm_up(WIDE)
    rng = np.random.default_rng(31)
    widest = []
    for _ in range(6):
        scene = make_scene(setup, sky, rng)
        result = identifier.identify(scene.spots, WIDE)
        assert result.solved, result.reason
        assert np.array_equal(result.hip, scene.hip[result.spot_index])
        # The widest pair of guide stars in view (up to the field diagonal) is a stored pair.
        in_view = np.flatnonzero(np.isin(database.hip, scene.hip))
        vectors = database.vectors[in_view]
        angles = np.arccos(np.clip(vectors @ vectors.T, -1.0, 1.0))
        a, b = np.unravel_index(np.argmax(angles), angles.shape)
        stored_a, stored_b = database.pairs_in_range(angles[a, b] - 1e-9, angles[a, b] + 1e-9)
        assert {int(in_view[a]), int(in_view[b])} in [{int(x), int(y)} for x, y in zip(stored_a, stored_b)]
        widest.append(angles[a, b])
    assert max(widest) > DatabaseConfig().max_pair_angle_rad  # pairs the default database does not hold


def test_fast_setup_database_is_the_default_pair_range():
    # van Bezooijen's FAST: 11.3 deg field, 16 deg diagonal, guide stars to 7.0.
    config = DatabaseConfig.for_camera(SETUPS["fast"].camera, magnitude_limit=7.0)
    assert config.max_pair_angle_rad == DatabaseConfig().max_pair_angle_rad and config.magnitude_limit == 7.0


@pytest.mark.parametrize("fov_deg", [3.0, 6.07])
def test_a_narrow_field_stores_only_the_pairs_it_can_see(fov_deg):
    # The openstartracker camera (1392 x 1040 px, 6.07 deg): 7.6 deg diagonal, pairs to 10 deg.
    camera = CameraModel.from_fov(1392, 1040, math.radians(fov_deg))
    config = DatabaseConfig.for_camera(camera, magnitude_limit=7.9)
    diagonal = widest_angle_on_the_border(camera)
    assert 1.1 * diagonal + math.radians(1.0) <= config.max_pair_angle_rad < 1.1 * diagonal + math.radians(2.0)
    assert config.max_pair_angle_rad <= 0.5 * DatabaseConfig().max_pair_angle_rad
