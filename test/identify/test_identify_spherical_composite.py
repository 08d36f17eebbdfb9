# SPDX-License-Identifier: Apache-2.0
"""
Cole & Crassidis' spherical triangle and Toloei's composite pyramid / planar triangle methods.

On seed-paper scenes with known truth.
"""
import time

import numpy as np
import pytest

from star_tracker.centroid import Spots
from star_tracker.identify import DatabaseConfig, IdentifyConfig, load_or_build_database
from star_tracker.identify.base import NO_MATCH, TIMEOUT
from star_tracker.identify.deep_catalog import deep_catalog_path
from star_tracker.identify.composite import CompositeIdentifier
from star_tracker.identify.spherical_triangle import (SphericalTriangleIdentifier, SphericalTriangleSettings,
                                                      join_assignments)
from star_tracker.identify.triangle_database import TriangleConfig, triangle_cache_path
from star_tracker.sim.scenes import SETUPS, make_scene

ALGORITHMS = [SphericalTriangleIdentifier, CompositeIdentifier]


@pytest.fixture(scope="module")
def sky(catalog):
    return catalog.at_epoch(2026.0)


@pytest.fixture(scope="module")
def cole_database():
    return load_or_build_database(DatabaseConfig(magnitude_limit=6.0, max_pair_angle_rad=float(np.radians(8.0))))


def score(identifier, setup, sky, count, seed):
    """(solved, wrong, CPU seconds per call) over `count` scenes; 'wrong' counts any wrong HIP id."""
    rng = np.random.default_rng(seed)
    solved = wrong = 0
    elapsed = []
    for _ in range(count):
        scene = make_scene(setup, sky, rng)
        started = time.process_time()
        result = identifier.identify(scene.spots, setup.camera)
        elapsed.append(time.process_time() - started)
        if result.solved:
            solved += 1
            wrong += int(np.any(result.hip != scene.hip[result.spot_index]))
    return solved, wrong, elapsed


@pytest.mark.parametrize("cls", ALGORITHMS)
def test_exact_hip_ids_on_nominal_scenes(cls, database, sky):
    # CPU-time budget: other load on the host must not turn solves into timeouts.
    config = IdentifyConfig(budget_clock="cpu")
    identifier = cls(database, config)
    solved, wrong, elapsed = score(identifier, SETUPS["nominal"], sky, 15, seed=21)
    assert wrong == 0
    assert solved >= 14
    assert max(elapsed) < config.max_time_s + 1.0


@pytest.mark.parametrize("cls", ALGORITHMS)
def test_exact_hip_ids_on_cole_scenes(cls, cole_database, sky):
    """
    Cole's 8 deg, magnitude 6.0 tracker.

    Fields with 3 stars or fewer cannot be solved (too few for a hypothesis plus
    verification); most others must be, all correctly.
    """
    identifier = cls(cole_database, IdentifyConfig())
    setup = SETUPS["cole"]
    rng = np.random.default_rng(22)
    solved = eligible = 0
    for _ in range(30):
        scene = make_scene(setup, sky, rng)
        result = identifier.identify(scene.spots, setup.camera)
        eligible += len(scene.spots) >= 5
        if result.solved:
            solved += 1
            assert np.all(result.hip == scene.hip[result.spot_index])
    assert solved >= 0.85 * eligible


def test_paper_mode_pivots_on_area_and_moment_alone(cole_database, sky):
    """
    Check that without the side check the pivots narrow the candidates down; results stay correct.

    The side check is Cole's finalists: area, polar moment, handedness.
    """
    identifier = SphericalTriangleIdentifier(cole_database, IdentifyConfig(),
                                             settings=SphericalTriangleSettings(side_check=False, max_leftover=0))
    setup = SETUPS["cole"]
    rng = np.random.default_rng(23)
    solved = pivots = 0
    for _ in range(20):
        scene = make_scene(setup, sky, rng)
        result = identifier.identify(scene.spots, setup.camera)
        if result.solved:
            solved += 1
            pivots += result.stats["chain_pivots"]
            assert np.all(result.hip == scene.hip[result.spot_index])
    assert solved >= 10 and pivots >= 1


def test_composite_finds_six_stars_among_fifty_false_ones(database, sky):
    identifier = CompositeIdentifier(database, IdentifyConfig(max_time_s=1.0, budget_clock="cpu"))
    solved, wrong, elapsed = score(identifier, SETUPS["toloei_6_50"], sky, 5, seed=24)
    assert wrong == 0 and solved >= 3
    assert max(elapsed) < 1.0 + 1.0


def mirror(spots, width):
    return Spots(width - 1 - spots.x, spots.y, spots.flux, spots.snr, spots.cov, spots.flags, spots.area,
                 spots.peak, spots.width, spots.height)


@pytest.mark.parametrize("cls", ALGORITHMS)
def test_mirror_images_are_never_solved(cls, database, sky):
    config = IdentifyConfig(budget_clock="cpu")  # CPU time: other load on the host stretches only the wall time
    identifier = cls(database, config)
    setup = SETUPS["nominal"]
    rng = np.random.default_rng(25)
    for _ in range(8):
        scene = make_scene(setup, sky, rng)
        started = time.process_time()
        result = identifier.identify(mirror(scene.spots, setup.camera.width), setup.camera)
        assert not result.solved
        assert time.process_time() - started < config.max_time_s + 1.0


@pytest.mark.parametrize("cls", ALGORITHMS)
def test_random_spots_are_never_solved_and_time_is_bounded(cls, database, nominal_camera):
    config = IdentifyConfig(max_time_s=0.3, budget_clock="cpu")
    identifier = cls(database, config)
    rng = np.random.default_rng(26)
    for n in (5, 15, 40, 140):
        x, y = rng.uniform(0, 1023, n), rng.uniform(0, 1023, n)
        cov = np.tile(np.eye(2) * 0.09, (n, 1, 1))
        spots = Spots(x, y, rng.uniform(1, 100, n), np.full(n, 30.0), cov, np.zeros(n, np.uint32),
                      np.ones(n, np.int32), np.ones(n), 1024, 1024)
        started = time.process_time()
        result = identifier.identify(spots, nominal_camera)
        assert not result.solved and result.status in (NO_MATCH, TIMEOUT)
        assert time.process_time() - started < config.max_time_s + 1.0


def test_many_false_stars_stay_within_the_time_bound(database, sky):
    config = IdentifyConfig(max_time_s=0.3, budget_clock="cpu")
    setup = SETUPS["toloei_4_136"]
    scene = make_scene(setup, sky, np.random.default_rng(27))
    for cls in ALGORITHMS:
        started = time.process_time()
        result = cls(database, config).identify(scene.spots, setup.camera)
        assert time.process_time() - started < config.max_time_s + 1.0
        assert not result.solved or np.all(result.hip == scene.hip[result.spot_index])


def test_pivot_join_keeps_only_assignments_that_agree_on_the_shared_spots():
    # Chain over spots (0, 1, 2) with two assignments; pivot triangle (1, 2, 3).
    table = np.array([[10, 11, 12], [20, 21, 22]])
    pivot = np.array([[11, 12, 13], [21, 99, 23], [11, 12, 10]])
    spots, joined = join_assignments([0, 1, 2], table, np.array([1, 2, 3]), pivot, star_count=100)
    assert spots == [0, 1, 2, 3]
    np.testing.assert_array_equal(joined, [[10, 11, 12, 13]])  # star 10 twice is not one-to-one


def test_a_database_directory_holds_the_triangle_databases_too(catalog, tmp_path, monkeypatch):
    """
    Whoever passes a directory to load_or_build_database gets every database there.

    The triangle databases that spherical_triangle and composite build from it land beside
    the pair database, and nothing goes to the default cache.
    """
    default, chosen = tmp_path / "default", tmp_path / "chosen"
    monkeypatch.setenv("STAR_TRACKER_CACHE", str(default))
    config = DatabaseConfig(magnitude_limit=4.5, max_pair_angle_rad=float(np.radians(8.0)))
    database = load_or_build_database(config, chosen)
    for algorithm in ALGORITHMS:
        identifier = algorithm(database, IdentifyConfig())
        assert identifier.triangles.triangle_count > 0
    triangle_file = triangle_cache_path(database, TriangleConfig.for_database(database))
    assert triangle_file.parent == chosen and triangle_file.is_file()
    deep_file = deep_catalog_path(config.magnitude_limit + IdentifyConfig().deep_magnitude_margin, config.epoch_jyear,
                                  chosen)  # the deep re-match's catalog
    assert sorted(f.name for f in chosen.iterdir()) == sorted([f"pairs_{config.cache_key()}.npz", triangle_file.name,
                                                               deep_file.name])
    assert not default.exists() or not any(default.iterdir())
    # The same database loaded again from that directory still knows where it lives.
    assert load_or_build_database(config, chosen).cache_directory == chosen
