# SPDX-License-Identifier: Apache-2.0
"""
Property-based tests (hypothesis) of identification (star_tracker.identify) on faulty spots.

Spots as a faulty centroider could send them, through the identifier node's own input path
(convert.drop_invalid_spots, then identify): a proper rotation or no solution, never an
exception. Defects found by fuzzing are pinned at the end, each with its failing input
(docs/RELIABILITY.md, "Defects found by fuzzing in the core").
"""
from __future__ import annotations

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
pytest.importorskip("rclpy")  # convert.drop_invalid_spots lives with the message converters

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from star_tracker.centroid import Spots  # noqa: E402
from star_tracker.identify import ALGORITHMS, IdentifyConfig, make_identifier  # noqa: E402
from star_tracker.ros import convert  # noqa: E402

from fuzz_support import CAMERAS, edgy, examples, is_rotation  # noqa: E402


@pytest.fixture(scope="module")
def identifiers(database):
    config = IdentifyConfig(max_time_s=0.02)
    return {name: make_identifier(name, database, config) for name in sorted(ALGORITHMS)}


position = st.one_of(st.floats(0.0, 1023.0), edgy, st.floats(-1e6, 1e6))
variance = st.one_of(st.floats(0.0, 2.0), edgy, st.floats(-1e3, 1e6))


@st.composite
def spot_sets(draw, max_spots=30):
    """
    Spots as a faulty centroider could send them.

    NaN/inf/huge positions, fluxes and covariances, duplicates (one position repeated),
    empty.
    """
    n = draw(st.integers(0, max_spots))
    x = np.array(draw(st.lists(position, min_size=n, max_size=n)), float)
    y = np.array(draw(st.lists(position, min_size=n, max_size=n)), float)
    if n and draw(st.booleans()):
        dup = draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=n))
        x[dup], y[dup] = x[dup[0]], y[dup[0]]
    flux = np.array(draw(st.lists(st.one_of(st.floats(1.0, 1e5), edgy), min_size=n, max_size=n)), float)
    var = np.array(draw(st.lists(variance, min_size=2 * n, max_size=2 * n)), float).reshape(n, 2)
    cov = np.zeros((n, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = var[:, 0], var[:, 1]
    cov[:, 0, 1] = cov[:, 1, 0] = draw(st.sampled_from([0.0, 0.01, -5.0, np.nan]))
    return Spots(x, y, flux, np.full(n, 10.0), cov, np.zeros(n, np.uint32), np.ones(n, np.int32), np.ones(n),
                 1024, 1024)


@examples(200)
@given(spot_sets(), st.sampled_from(sorted(ALGORITHMS)), st.sampled_from(sorted(CAMERAS)))
def test_identify_after_the_nodes_input_checks_never_raises(identifiers, spots, algorithm, camera_name):
    """
    What the identifier node runs for a received spots message.

    drop_invalid_spots, then (with at least one spot left) identify.
    """
    kept, dropped = convert.drop_invalid_spots(spots)
    if len(kept) == 0:
        return  # the node reports too_few_spots without calling identify
    result = identifiers[algorithm].identify(kept, CAMERAS[camera_name])
    if result.solved:
        assert is_rotation(result.attitude.rotation)
        assert np.all(result.spot_index < len(kept))


# ============================================================================ defects found, fixed
def test_identify_with_an_infinite_covariance(identifiers):
    """
    Found by fuzzing.

    An infinite spot covariance raised OverflowError (int(inf) in KVector.range) or stalled
    hybrid and composite for seconds. Random spots are no stars: every algorithm returns
    without a solution, and says why.
    """
    rng = np.random.default_rng(1)
    n = 20
    spots = Spots(rng.uniform(0, 1023, n), rng.uniform(0, 1023, n), rng.uniform(10, 1e3, n), np.full(n, 10.0),
                  np.full((n, 2, 2), np.inf), np.zeros(n, np.uint32), np.ones(n, np.int32), np.ones(n), 1024, 1024)
    for name, identifier in identifiers.items():
        result = identifier.identify(spots, CAMERAS["nominal"])
        assert result.status in ("no_match", "timeout"), (name, result.status, result.reason)
        assert result.reason and result.attitude is None, name


def test_identify_with_coincident_spots(identifiers):
    """
    Found by fuzzing: hybrid raised ZeroDivisionError (kernels.triad, parallel rays) for two spots at the same position.

    Four spots at one position and one beside them are two distinct directions: too few to
    identify.
    """
    n = 5
    cov = np.tile(np.eye(2), (n, 1, 1))
    spots = Spots(np.zeros(n), np.array([0.0, 0.0, 0.0, 0.0, 6.0]), np.ones(n), np.full(n, 10.0), cov,
                  np.zeros(n, np.uint32), np.ones(n, np.int32), np.ones(n), 1024, 1024)
    result = identifiers["hybrid"].identify(spots, CAMERAS["nominal"])
    assert result.status == "too_few_spots", result.reason
