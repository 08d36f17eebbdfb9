"""Tracking through the real nodes (separate processes, Fast DDS): a slew with an occulted
frame, checked against the simulator's truth. No ROS mocks."""
from __future__ import annotations

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_integration import FRAMES, ros_graph, run_pipeline  # noqa: E402,F401  (same harness and fixture)

ARCSEC = np.radians(1 / 3600)
BLANK = 30  # frame index of the occulted frame


@pytest.mark.integration
def test_slew_is_tracked_through_the_nodes_and_a_loss_reacquires(ros_graph, tmp_path):
    # 2 deg/s coast, 1 deg/s^2 ramps (2 s each) starting 1 s in; the 30th frame is occulted.
    camera = {"attitude.profile": "slew", "attitude.slew.axis": [0.6, 0.8, 0.0], "attitude.slew.angle_deg": 8.0,
              "attitude.slew.max_rate_deg_s": 2.0, "attitude.slew.accel_deg_s2": 1.0, "attitude.slew.start_s": 1.0,
              "faults.blank_frames": [BLANK]}
    diagnostics: dict = {}
    # The centroider is aided by the identifier's own rate, which lags the 1 deg/s^2 ramps by a
    # frame or two at 5 Hz: the centroider must notice and measure those frames without the aid
    # (a trusted lagging aid once gave biased attitudes 100" off with 0.7" sigmas).
    frames, codes, logs, camera_diagnostics = run_pipeline(ros_graph, tmp_path, camera, diagnostics)
    assert codes == {"camera_simulator": 0, "centroider": 0, "identifier": 0}, logs
    assert not any("Traceback" in text for text in logs.values()), logs
    truth = [f for f in frames if f.truth is not None]
    # A host stall makes the camera skip frames (counted, logged; CI once: 11 in 3 stalls of
    # ~2 s): the tracker is judged on the frames that exist, across the gaps.
    skipped = int(camera_diagnostics.get("frames_skipped_overrun", "0"))
    assert len(truth) + skipped == FRAMES and len(truth) >= 45, logs["camera_simulator.log"]
    index = {f.stamp_ns: k for k, f in enumerate(truth)}
    period = int(round(np.median(np.diff([f.stamp_ns for f in truth]))))
    blank_ns = truth[0].stamp_ns + BLANK * period  # the grid is exact (test_integration checks it)

    published = [f for f in truth if f.attitude is not None]
    errors = np.array([f.error() for f in published])
    assert np.all(errors[:, 2] < 60 * ARCSEC), errors.max(axis=0) / ARCSEC  # never a wrong attitude
    assert np.all(errors[:, 0] < 10 * ARCSEC), errors[:, 0].max() / ARCSEC
    # Every frame but the occulted one is identified: tracking keeps up through the slew ...
    missing = [f.stamp_ns for f in truth if f.attitude is None]
    assert set(missing) <= {blank_ns}, [index[ns] for ns in missing]
    # ... and the frame after the occultation is identified (re-acquired within one frame).
    after = [f for f in truth if f.stamp_ns > blank_ns][:1]
    assert after and after[0].attitude is not None

    # The published rate matches the truth within its stated sigma.
    rated = [f for f in published if f.rate is not None and f.truth_rate is not None]
    assert len(rated) >= 0.9 * len(published)
    normalized = np.array([(f.rate - f.truth_rate) / np.sqrt(np.diag(f.rate_covariance)) for f in rated])
    assert np.all(np.sqrt(np.mean(normalized**2, axis=0)) < 2.0), np.sqrt(np.mean(normalized**2, axis=0))
    assert np.mean(np.abs(normalized) > 4.0) < 0.05, np.abs(normalized).max(axis=0)
    # The mode is reported: tracking after the first lost-in-space solve.
    centroider = diagnostics["star_tracker/centroider"]
    assert int(centroider.get("frames_rate_aided", "0")) >= 5, centroider  # the aid was in use
    identifier = diagnostics["star_tracker/identifier"]
    assert identifier["mode"] == "tracking", identifier
    assert int(identifier["frames_tracking"]) >= len(published) - 3, identifier
