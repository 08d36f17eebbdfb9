# SPDX-License-Identifier: Apache-2.0
"""The identifier's smear_aid inputs, joined to frames by stamp (duck-typed messages: no ROS needed)."""
import threading
from types import SimpleNamespace

import numpy as np

from star_tracker.centroid.streak.exposure_path import PATH_FIT_RESIDUAL_FRACTION
from star_tracker.ros.smear_aid_input import KEPT, SmearAidInput


def message(stamp_ns, vector):
    stamp = SimpleNamespace(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp, frame_id="star_tracker_optical"),
                           vector=SimpleNamespace(x=vector[0], y=vector[1], z=vector[2]))


def test_a_frame_gets_the_rate_and_acceleration_stamped_as_it():
    rejected = []
    aid = SmearAidInput(lambda counter, text: rejected.append(counter))
    assert aid.applied_for(5_000_000_000, wait_s=0.0) is None and not aid.received  # no centroider aid at all
    aid.on_rate(message(5_000_000_000, (0.01, 0.02, 0.0)))
    aid.on_acceleration(message(5_000_000_000, (0.03, 0.0, 0.0)))
    aid.on_acceleration(message(5_100_000_000, (0.0, 0.0, 0.0)))  # measured without rate aid or acceleration
    applied = aid.applied_for(5_000_000_000)
    assert np.allclose(applied.angular_velocity_rad_s, (0.01, 0.02, 0.0))
    assert np.allclose(applied.angular_acceleration_rad_s2, (0.03, 0.0, 0.0))
    plain = aid.applied_for(5_100_000_000)
    assert plain.angular_velocity_rad_s is None and plain.angular_acceleration_rad_s2 is None
    assert aid.applied_for(5_200_000_000, wait_s=0.0) is None  # this frame's aid was lost: not known
    aid.on_acceleration(message(5_300_000_000, (np.nan, 0.0, 0.0)))
    assert rejected == ["smear_aid_rejected"] and aid.applied_for(5_300_000_000, wait_s=0.0) is None


def test_the_worker_waits_briefly_for_an_aid_still_in_flight():
    aid = SmearAidInput(lambda counter, text: None)
    aid.on_acceleration(message(1_000_000_000, (0.0, 0.0, 0.0)))
    late = threading.Timer(0.05, aid.on_acceleration, (message(1_100_000_000, (0.0, 0.1, 0.0)),))
    late.start()
    applied = aid.applied_for(1_100_000_000, wait_s=10.0)  # returns when it arrives
    late.join()
    assert np.allclose(applied.angular_acceleration_rad_s2, (0.0, 0.1, 0.0))


def test_only_the_newest_frames_are_kept():
    aid = SmearAidInput(lambda counter, text: None)
    for k in range(KEPT + 10):
        aid.on_acceleration(message(k * 100_000_000, (0.0, 0.0, float(k))))
    assert aid.applied_for(0, wait_s=0.0) is None
    assert aid.applied_for((KEPT + 9) * 100_000_000, wait_s=0.0).angular_acceleration_rad_s2[2] == KEPT + 9
    aid.clear()
    assert not aid.received


def test_a_frame_fitted_on_a_gyros_path_gets_its_offset_and_the_path_residual():
    aid = SmearAidInput(lambda counter, text: None)
    offset = (2e-5, -1e-4, 0.0)  # rad: about 21" from mid-exposure to the exposure average
    aid.on_rate(message(7_000_000_000, (0.001, 0.007, 0.0)))
    aid.on_path_offset(message(7_000_000_000, offset))
    aid.on_acceleration(message(7_000_000_000, (0.0, 0.0, 0.0)))  # none applied on a path
    applied = aid.applied_for(7_000_000_000)
    assert np.allclose(applied.exposure_path_offset_rad, offset) and applied.angular_acceleration_rad_s2 is None
    sigma = np.sqrt(np.diag(applied.path_residual_covariance()))
    assert np.allclose(sigma, PATH_FIT_RESIDUAL_FRACTION * np.linalg.norm(offset))
    # An offset without the rate it was fitted with (that message lost) is not a path fit.
    aid.on_path_offset(message(7_100_000_000, offset))
    aid.on_acceleration(message(7_100_000_000, (0.0, 0.0, 0.0)))
    lone = aid.applied_for(7_100_000_000)
    assert lone.exposure_path_offset_rad is None and lone.path_residual_covariance() is None
