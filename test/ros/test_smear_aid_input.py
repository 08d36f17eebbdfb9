# SPDX-License-Identifier: Apache-2.0
"""The identifier's smear_aid inputs, joined to frames by stamp (no running ROS needed)."""
import threading
from types import SimpleNamespace

import numpy as np

from star_tracker.ros import convert
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


def path_message(stamp_ns, offset, covariance):
    return convert.path_offset_msg(np.asarray(offset), covariance, stamp_ns, "star_tracker_optical")


def test_a_frame_fitted_on_a_gyros_path_gets_its_offset_and_covariance():
    rejected = []
    aid = SmearAidInput(lambda counter, text: rejected.append(counter))
    offset = np.array([2e-5, -1e-4, 0.0])  # rad: about 21" from the exposure average to mid-exposure
    covariance = np.diag([1.0, 2.0, 3.0]) * 1e-12
    aid.on_rate(message(7_000_000_000, (0.001, 0.007, 0.0)))
    aid.on_path_offset(path_message(7_000_000_000, offset, covariance))
    aid.on_acceleration(message(7_000_000_000, (0.0, 0.0, 0.0)))  # none applied on a path
    applied = aid.applied_for(7_000_000_000)
    assert np.allclose(applied.exposure_path_offset_rad, offset, rtol=0, atol=1e-12)
    assert np.allclose(applied.exposure_path_offset_covariance, covariance)
    assert applied.angular_acceleration_rad_s2 is None
    # An offset without the rate it was fitted with (that message lost) is not a path fit.
    aid.on_path_offset(path_message(7_100_000_000, offset, covariance))
    aid.on_acceleration(message(7_100_000_000, (0.0, 0.0, 0.0)))
    lone = aid.applied_for(7_100_000_000)
    assert lone.exposure_path_offset_rad is None and lone.exposure_path_offset_covariance is None
    # A malformed offset (a quaternion not of unit norm, a covariance not positive) is counted and ignored.
    bad = path_message(7_200_000_000, offset, covariance)
    bad.pose.pose.orientation.w = 2.0
    aid.on_path_offset(bad)
    aid.on_path_offset(path_message(7_200_000_000, offset, -covariance))
    assert rejected == ["smear_aid_rejected"] * 2
