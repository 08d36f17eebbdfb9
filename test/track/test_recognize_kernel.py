# SPDX-License-Identifier: Apache-2.0
"""
A tracked frame's one-call local recognition (recognize_kernel) against the Python steps it stands in for.

Tracker.track runs the common path in one compiled call and hands the rare branches to
Tracker._track_steps / StarIdentifier.solved: both must publish the same result to the bit.
Real renderer, real centroider, real database; predictions from the tracker itself, and
wrong, wide and starved ones.
"""
import math
import time

import numpy as np
import pytest

from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.identify import IdentifyConfig, make_identifier
from star_tracker.models.attitude import attitude_error, radec_roll_to_matrix, rotation_vector_to_matrix
from star_tracker.sim.motion import SlewMotion
from star_tracker.sim.render import StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel
from star_tracker.track import recognize_kernel, tracking
from star_tracker.track.tracking import MODE_TRACKING, Prediction, Tracker

from same_identification import assert_same, count_verdicts

ARCSEC = math.pi / 180 / 3600


@pytest.fixture()
def verdicts(monkeypatch):
    """Count the one-call kernel's verdicts: the branch each frame took."""
    return count_verdicts(monkeypatch, tracking.recognize_kernel, "recognize")


def assert_same_frame(tracker, spots, camera, prediction):
    """Tracker.track and its Python steps agree on (result, gate); return the result."""
    fused, gate = tracker.track(spots, camera, prediction)
    steps, steps_gate = tracker._track_steps(spots, camera, prediction, time.perf_counter())
    assert_same(fused, steps)
    assert gate == steps_gate
    return fused


def test_same_result_on_every_branch(catalog, database, nominal_camera, verdicts):
    # No wall-clock budget: a loaded host must not time out the first frame's solve.
    tracker = Tracker(make_identifier("hybrid", database, IdentifyConfig(max_time_s=60.0)))
    tracker.warm_up(nominal_camera)
    renderer = StarFieldRenderer(nominal_camera, SensorModel(), catalog, magnitude_limit=7.5)
    # A slew of 5 deg after 0.3 s at rest: 2 deg/s^2 to 1.5 deg/s (streaks, the rate aid, an acceleration).
    motion = SlewMotion(radec_roll_to_matrix(1.2, 0.4, 0.2), np.array([0.6, 0.8, 0.0]), np.radians(5.0),
                        np.radians(1.5), np.radians(2.0), t_start=0.3)
    tracked = 0
    for k in range(20):
        stamp_ns = int(round((0.05 + 0.1 * k) * 1e9))
        frame = renderer.render(motion, stamp_ns * 1e-9, frame_seed(3, k))
        spots = extract_spots(frame.image, CentroidConfig(), tracker.centroider_aid(stamp_ns, nominal_camera, 0.1))
        prediction = tracker.predict(stamp_ns)
        if prediction is not None:
            result = assert_same_frame(tracker, spots, nominal_camera, prediction)
            if result.solved:
                cross, roll, _ = attitude_error(result.attitude.rotation, frame.truth.rotation)
                assert cross < 5 * ARCSEC and roll < 20 * ARCSEC
            # A prediction off by more than its gate, a wide one (the displacement voted), too few spots.
            wrong = frame.truth.rotation @ rotation_vector_to_matrix(np.radians([0.3, -0.3, 0.15]))
            assert not assert_same_frame(tracker, spots, nominal_camera,
                                         Prediction(stamp_ns, wrong, np.eye(3) * (20 * ARCSEC) ** 2)).solved
            assert_same_frame(tracker, spots, nominal_camera,
                              Prediction(stamp_ns, prediction.rotation, np.eye(3) * np.radians(0.05) ** 2))
            assert_same_frame(tracker, spots.take(np.arange(2)), nominal_camera, prediction)
        tracked += tracker.process(stamp_ns, spots, nominal_camera).mode == MODE_TRACKING
    assert tracked >= 18
    assert verdicts.get(recognize_kernel.SOLVED, 0) >= 18
    assert verdicts.get(recognize_kernel.VOTE_IN_PYTHON, 0) >= 1
    assert verdicts.get(recognize_kernel.TOO_FEW_SPOTS, 0) >= 18
    failures = (recognize_kernel.TOO_FEW_STARS_NEAR, recognize_kernel.TOO_FEW_PAIRS, recognize_kernel.TOO_FEW_VERIFIED,
                recognize_kernel.OUTSIDE_GATE, recognize_kernel.BOUND_FAILED)
    failed = sum(verdicts.get(v, 0) for v in failures)
    assert failed >= 18
