# SPDX-License-Identifier: Apache-2.0
"""
The hybrid identifier's one-call solve (solve_kernel) against the Python steps it stands in for.

HybridIdentifier.identify runs prepare, the first batch of the search, the final fit and the
deep re-match in one compiled call, and hands over to StarIdentifier's Python steps where a
rare branch starts. Both must publish the same result to the bit, on every branch.
"""
import numpy as np
import pytest

from star_tracker.identify import IdentifyConfig, hybrid, make_identifier, solve_kernel
from star_tracker.identify.base import StarIdentifier
from star_tracker.identify.geometry import pyramid_triangles
from star_tracker.sim.scenes import SETUPS, make_scene

from same_identification import assert_same, count_verdicts


@pytest.fixture()
def verdicts(monkeypatch):
    """Count the one-call kernel's verdicts: the branch each frame took."""
    return count_verdicts(monkeypatch, hybrid.solve_kernel, "solve")


def test_pyramid_order_is_mortaris():
    """pyramid_triangles (compiled pyramid_rows) against the order written out: gaps j - i, then k - j, then i."""
    for n in range(0, 14):
        expected = [(i, i + dj, i + dj + dk) for dj in range(1, n - 1) for dk in range(1, n - dj)
                    for i in range(n - dj - dk)]
        got = pyramid_triangles(n)
        assert got.shape == (len(expected), 3)
        assert [tuple(row) for row in got.tolist()] == expected


def test_same_result_on_every_branch(database, catalog, verdicts):
    camera = SETUPS["nominal"].camera
    identifier = make_identifier("hybrid", database, IdentifyConfig(max_time_s=60.0))
    rng = np.random.default_rng(47)
    scenes = [make_scene(SETUPS["nominal"], catalog, rng) for _ in range(40)]
    # Many false spots among few stars: the first batch of triangles often verifies nothing.
    scenes += [make_scene(SETUPS["toloei_6_50"], catalog, rng) for _ in range(6)]
    solved_right = 0
    for scene in scenes:
        fused = identifier.identify(scene.spots, camera)
        assert_same(fused, StarIdentifier.identify(identifier, scene.spots, camera))
        if fused.solved:
            assert np.array_equal(fused.hip, scene.hip[fused.spot_index])
            solved_right += 1
    # Too few spots.
    assert_same(identifier.identify(scenes[0].spots.take(np.arange(2)), camera),
                StarIdentifier.identify(identifier, scenes[0].spots.take(np.arange(2)), camera))
    # The lever-arm examination is Python's: with every limit at zero each match goes there.
    identifier._lever_limits[:] = 0.0
    for scene in scenes[:5]:
        assert_same(identifier.identify(scene.spots, camera), StarIdentifier.identify(identifier, scene.spots, camera))
    assert solved_right >= 40
    assert verdicts.get(solve_kernel.SOLVED, 0) >= 30
    assert verdicts.get(solve_kernel.NOT_FOUND, 0) >= 1
    assert verdicts.get(solve_kernel.TOO_FEW_SPOTS, 0) == 1
    assert verdicts.get(solve_kernel.FINISH_IN_PYTHON, 0) >= 5
