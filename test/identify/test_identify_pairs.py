# SPDX-License-Identifier: Apache-2.0
"""
Pair-based lost-in-space identification.

Cole & Crassidis' angle method with pivoting and van Bezooijen's match groups (FAST), scored
against scene truth (exact HIP ids).
"""
from dataclasses import replace

import numpy as np
import pytest

from star_tracker.centroid import Spots
from star_tracker.identify import DatabaseConfig, IdentifyConfig, load_or_build_database
from star_tracker.identify.angle_pivot import AnglePivotConfig, AnglePivotIdentifier, pair_angle_sigma
from star_tracker.identify.hybrid import HybridIdentifier
from star_tracker.identify.match_groups import MatchGroupConfig, MatchGroupIdentifier
from star_tracker.sim.scenes import SETUPS, make_scene

ALGORITHMS = {"angle_pivot": AnglePivotIdentifier, "match_groups": MatchGroupIdentifier}


@pytest.fixture(scope="module")
def sky(catalog):
    return catalog.at_epoch(2026.0)


@pytest.fixture(scope="module")
def databases(database):
    """
    Pattern databases per setup.

    The nominal default; the seed papers' cameras get pairs up to their FOV diameter and guide
    stars to their sensitivity.
    """
    return {
        "nominal": database,
        "cole": load_or_build_database(DatabaseConfig(magnitude_limit=6.0, max_pair_angle_rad=np.radians(8.0))),
        "fast": load_or_build_database(DatabaseConfig(magnitude_limit=7.0, max_pair_angle_rad=np.radians(11.3))),
    }


def scenes(setup_name, sky, database, count, seed, min_guide_stars=6):
    """Return the first `count` scenes with at least `min_guide_stars` spots of database stars."""
    rng = np.random.default_rng(seed)
    found = []
    while len(found) < count:
        scene = make_scene(SETUPS[setup_name], sky, rng)
        if np.isin(scene.hip, database.hip).sum() >= min_guide_stars:
            found.append(scene)
    return found


def assert_exact(result, scene):
    assert result.solved, result.reason
    assert result.hip.size >= 4
    assert np.all(result.hip == scene.hip[result.spot_index]), (result.hip, scene.hip[result.spot_index])


def mirrored(spots: Spots) -> Spots:
    return replace(spots, x=spots.width - 1 - spots.x)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
@pytest.mark.parametrize("setup_name", ["nominal", "cole", "fast"])
def test_identifies_exact_hip_ids(algorithm, setup_name, sky, databases):
    database = databases[setup_name]
    # Judged by the identities, not host speed: the first call also loads compiled kernels.
    identifier = ALGORITHMS[algorithm](database, IdentifyConfig(max_time_s=5.0))
    for scene in scenes(setup_name, sky, database, 5, seed=21):
        assert_exact(identifier.identify(scene.spots, scene.setup.camera), scene)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_mirror_image_is_never_solved(algorithm, sky, databases):
    for setup_name in ("nominal", "fast"):
        database = databases[setup_name]
        identifier = ALGORITHMS[algorithm](database, IdentifyConfig())
        for scene in scenes(setup_name, sky, database, 5, seed=22):
            assert not identifier.identify(mirrored(scene.spots), scene.setup.camera).solved


# Random-spot scenes and the time budget are tested for every registered algorithm in
# test_identify.py.


def test_match_groups_solve_without_magnitudes(sky, databases):
    database = databases["fast"]
    identifier = MatchGroupIdentifier(database, IdentifyConfig())
    for k, scene in enumerate(scenes("fast", sky, database, 5, seed=25)):
        # All unknown (the scene order stays: brightest first), or every other one unknown.
        flux = scene.spots.flux.copy()
        flux[:: 1 if k % 2 == 0 else 2] = np.nan
        result = identifier.identify(replace(scene.spots, flux=flux), scene.setup.camera)
        assert_exact(result, scene)


def test_match_groups_find_six_stars_among_fifty_false(sky, database):
    """Toloei's setup: 6 real stars among 56 spots; every spot may form patterns."""
    identifier = MatchGroupIdentifier(database, IdentifyConfig(max_pattern_spots=56, max_time_s=5.0))
    for scene in scenes("toloei_6_50", sky, database, 2, seed=26):
        result = identifier.identify(scene.spots, scene.setup.camera)
        assert_exact(result, scene)
        assert result.stats["largest_group"] >= 6


def test_magnitudes_prune_pair_matches(sky, databases):
    database = databases["fast"]
    identifier = MatchGroupIdentifier(database, IdentifyConfig())
    scene = scenes("fast", sky, database, 1, seed=27)[0]
    with_magnitudes = identifier.identify(scene.spots, scene.setup.camera).stats
    without = identifier.identify(replace(scene.spots, flux=np.full(len(scene.spots), np.nan)),
                                  scene.setup.camera).stats
    assert with_magnitudes["pair_matches"] == without["pair_matches"]
    assert without["oriented_matches"] == 2 * without["pair_matches"]
    assert with_magnitudes["oriented_matches"] < 0.9 * without["oriented_matches"]


def test_angle_pivot_records_pivots_and_runs_the_paper_variant(sky, databases):
    database = databases["cole"]
    paper = AnglePivotConfig(order_by="angle", max_left_out=0, restart=False, skip_empty_pivots=False)
    for config in (AnglePivotConfig(), paper):
        identifier = AnglePivotIdentifier(database, IdentifyConfig(), config)
        solved = 0
        for scene in scenes("cole", sky, database, 5, seed=28, min_guide_stars=7):
            result = identifier.identify(scene.spots, scene.setup.camera)
            if result.solved:
                solved += 1
                assert_exact(result, scene)
                assert 1 <= result.stats["pivots"] <= config.pivot_limit
                assert result.stats["chains"] >= 1
        assert solved >= 4


def rotation_error_rad(result, scene) -> float:
    """Angle of the rotation between the solved and the true attitude [rad]."""
    delta = result.attitude.rotation.T @ scene.rotation
    return float(np.arccos(np.clip(0.5 * (np.trace(delta) - 1.0), -1.0, 1.0)))


# Cole scenes (seed 1) on which angle_pivot's solved chain once left the brightest spot out, so
# the attitude fitted to the rest put its star beyond the verification radius: 5 of 6 stars at
# 89" (scene 152), 4 of 5 at 50" (scene 271), where every other algorithm matched all.
COLE_SCENES = list(range(12)) + [152, 271]


def test_angle_pivot_matches_as_many_stars_as_hybrid_on_cole_scenes(sky, databases):
    database = databases["cole"]
    config = IdentifyConfig(max_time_s=5.0)  # judged by outcome, not by host speed
    pivot, hybrid = AnglePivotIdentifier(database, config), HybridIdentifier(database, config)
    rng = np.random.default_rng(1)
    scenes = [make_scene(SETUPS["cole"], sky, rng) for _ in range(max(COLE_SCENES) + 1)]
    compared = 0
    for index in COLE_SCENES:
        scene = scenes[index]
        ours, theirs = pivot.identify(scene.spots, scene.setup.camera), hybrid.identify(scene.spots, scene.setup.camera)
        if not theirs.solved:
            continue  # too few stars for anyone
        assert_exact(ours, scene)
        assert ours.hip.size >= theirs.hip.size, (index, ours.hip.size, theirs.hip.size)
        arcsec = np.radians(1.0 / 3600.0)
        assert rotation_error_rad(ours, scene) <= 1.5 * rotation_error_rad(theirs, scene) + 5.0 * arcsec, index
        compared += 1
    assert compared >= 6


def test_match_groups_report_threshold_and_groups(sky, databases):
    database = databases["fast"]
    identifier = MatchGroupIdentifier(database, IdentifyConfig())
    scene = scenes("fast", sky, database, 1, seed=29, min_guide_stars=8)[0]
    result = identifier.identify(scene.spots, scene.setup.camera)
    assert_exact(result, scene)
    assert result.stats["threshold"] >= 1 and result.stats["largest_group"] == 8


def test_angle_sigma_matches_monte_carlo():
    """Cole & Crassidis eq. 12/14: the inter-star angle error is sqrt(sigma_i^2 + sigma_j^2)."""
    rng = np.random.default_rng(30)
    sigma_i, sigma_j, theta = 87e-6, 40e-6, np.radians(5.0)
    a = np.tile([0.0, 0.0, 1.0], (20000, 1))
    b = np.tile([np.sin(theta), 0.0, np.cos(theta)], (20000, 1))
    a = a + rng.normal(scale=sigma_i, size=a.shape) * [1, 1, 0]
    b = b + rng.normal(scale=sigma_j, size=b.shape) * [np.cos(theta), 1, -np.sin(theta)]
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    angles = np.arccos(np.sum(a * b, axis=1))
    assert np.std(angles) == pytest.approx(float(pair_angle_sigma(sigma_i, sigma_j)), rel=0.03)
    assert float(pair_angle_sigma(1e-4, 1e-4)) == pytest.approx(np.sqrt(2) * 1e-4, rel=1e-6)


def test_configs_are_validated():
    with pytest.raises(ValueError):
        AnglePivotConfig(pivot_limit=0)
    with pytest.raises(ValueError):
        AnglePivotConfig(order_by="brightness")
    with pytest.raises(ValueError):
        MatchGroupConfig(magnitude_tolerance=0.0)
    with pytest.raises(ValueError):
        MatchGroupConfig(icmaxr=0)
