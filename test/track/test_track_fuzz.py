# SPDX-License-Identifier: Apache-2.0
"""
Property-based tests (hypothesis) of tracking and rate estimation (star_tracker.track).

With stamps as a faulty or replayed stream delivers them: duplicated, backward, far apart.
Never a wrong attitude, never a non-finite rate, never an exception other than the documented
refusal (pinned at the end, docs/RELIABILITY.md, "Defects found by fuzzing in the core").
"""
from __future__ import annotations

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from star_tracker.models.attitude import attitude_error, radec_roll_to_matrix, rotation_vector_to_matrix  # noqa: E402
from star_tracker.identify import IdentifyConfig, make_identifier  # noqa: E402
from star_tracker.sim.motion import ConstantRateMotion  # noqa: E402
from star_tracker.track.rate import AttitudeRateEstimator  # noqa: E402
from star_tracker.track.tracking import Tracker  # noqa: E402

from conftest import spots_at  # noqa: E402
from fuzz_support import CAMERAS, examples, refused  # noqa: E402


@pytest.fixture(scope="module")
def sky(catalog):
    return catalog.brighter_than(6.8).at_epoch(2026.0)


@examples(30)
@given(st.lists(st.integers(0, 12), min_size=2, max_size=8), st.floats(0.0, 2 * np.pi), st.floats(-1.4, 1.4))
def test_tracker_with_duplicate_and_backward_stamps_never_publishes_a_wrong_attitude(database, sky, stamps, ra, dec):
    """
    Frames 100 ms apart on a 1 deg/s slew, delivered in any order with repeats.

    The tracker solves them or not, but every solved attitude is the true one at that frame's
    stamp and every rate is finite.
    """
    camera = CAMERAS["nominal"]
    motion = ConstantRateMotion(radec_roll_to_matrix(ra, dec, 0.3), np.radians([1.0, -0.5, 0.2]))
    tracker = Tracker(make_identifier("hybrid", database, IdentifyConfig(max_time_s=0.2)))
    for k in stamps:
        stamp_ns = 1_000_000_000 + k * 100_000_000
        truth = motion.rotation_at(stamp_ns * 1e-9)
        frame = tracker.process(stamp_ns, spots_at(sky, camera, truth), camera)
        if frame.solved:
            assert attitude_error(frame.identification.attitude.rotation, truth)[2] < np.radians(10 / 3600)
        if frame.rate is not None:
            assert np.all(np.isfinite(frame.rate.angular_velocity)) and np.all(np.isfinite(frame.rate.covariance))


@st.composite
def attitude_streams(draw):
    """(stamp, rotation, covariance) with repeated, backward and far-apart stamps."""
    rows = []
    for _ in range(draw(st.integers(1, 12))):
        stamp = draw(st.one_of(st.integers(0, 3_000_000_000), st.sampled_from([0, 1, 100_000_000, 2**62])))
        rotvec = np.array(draw(st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3)))
        sigma = draw(st.sampled_from([1e-12, 1e-6, 1e-3, 1.0]))
        rows.append((stamp, rotation_vector_to_matrix(rotvec), np.eye(3) * sigma**2))
    return rows


@examples(300)
@given(attitude_streams(), st.floats(0.01, 10.0), st.floats(0.0, 1.0))
def test_rate_estimator_with_out_of_order_and_duplicate_stamps(stream, window_s, alpha):
    estimator = AttitudeRateEstimator(window_s, alpha)
    for stamp_ns, rotation, covariance in stream:
        rate = estimator.add(stamp_ns, rotation, covariance)
        if rate is not None:
            assert rate.stamp_ns == stamp_ns and rate.frames >= 2
            assert np.all(np.isfinite(rate.angular_velocity)) and np.all(np.isfinite(rate.covariance))


# ============================================================================ defects found, fixed
def test_rate_estimator_refuses_a_singular_covariance():
    """Found by fuzzing: a singular attitude covariance raised LinAlgError; the documented refusal is a ValueError."""
    refused(AttitudeRateEstimator().add, 1, np.eye(3), np.zeros((3, 3)), match="covariance must be invertible")
