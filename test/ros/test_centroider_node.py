# SPDX-License-Identifier: Apache-2.0
"""centroider node over DDS: streaks measured at mid-exposure, with and without the rate aid."""
from __future__ import annotations

import time

import numpy as np
import pytest
pytestmark = pytest.mark.slow  # every test here starts processes (nodes or node executables)

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import QuaternionStamped  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402

from star_tracker.centroid import FLAG_RATE_AIDED, FLAG_STREAK  # noqa: E402
from star_tracker.ros import convert  # noqa: E402
from star_tracker.ros.qos import RESULT_QOS, SPOTS_QOS  # noqa: E402
from conftest import join_isolated_ros_domain  # noqa: E402
from star_tracker.ros.pipeline import NodeProcesses  # noqa: E402

RATE_DEG_S = [1.5, 1.0, 0.0]  # 1.8 deg/s across the boresight: ~12 px streaks in 0.1 s
FRAMES = 8


def run_pipeline(tmp_path, monkeypatch, centroider_params, remaps=None, camera_params=None):
    """
    Run camera_simulator + centroider.

    Returns {stamp: (spots records, truth records)} and the centroider's last diagnostics values.
    camera_params override the camera's (streaks by default).
    """
    env = join_isolated_ros_domain(monkeypatch)
    node = rclpy.create_node("centroider_probe")
    spots, truth, diag = {}, {}, {}
    node.create_subscription(PointCloud2, "spots", lambda m: spots.__setitem__(
        convert.stamp_to_ns(m.header.stamp), convert.cloud_to_records(m, convert.SPOT_FIELDS, convert.SPOT_DTYPE)),
        SPOTS_QOS)
    node.create_subscription(PointCloud2, "truth/objects", lambda m: truth.__setitem__(
        convert.stamp_to_ns(m.header.stamp),
        convert.cloud_to_records(m, convert.TRUTH_OBJECT_FIELDS, convert.TRUTH_OBJECT_DTYPE)), RESULT_QOS)

    node.create_subscription(QuaternionStamped, "truth/attitude", lambda _m: None, RESULT_QOS)  # camera waits for it

    def on_diag(msg):
        for status in msg.status:
            if status.name.endswith("/centroider"):
                diag.update({kv.key: kv.value for kv in status.values})
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    params = {"camera_simulator": {"attitude.profile": "constant_rate", "attitude.body_rate_deg_s": RATE_DEG_S,
                                   "max_frames": FRAMES, "rate_hz": 5.0, "wait_for_subscribers": True,
                                   "start_delay_s": 2.0, **(camera_params or {})},
              "centroider": {"saturation_adu": 60000.0, **centroider_params}}
    procs = NodeProcesses(env, tmp_path / "logs", params, nodes=("camera_simulator", "centroider"),
                          remaps=remaps).start()
    try:
        procs.wait_ready()
        # Until every frame is processed (the centroider's own count) and nothing more arrives:
        # a best-effort message lost on a loaded host must not stall the test.
        end = time.monotonic() + 60.0
        last_count, quiet_since = -1, time.monotonic()
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
            if len(spots) != last_count:
                last_count, quiet_since = len(spots), time.monotonic()
            done = int(diag.get("frames_processed", 0)) >= FRAMES and len(truth) >= FRAMES
            if done and (len(spots) >= FRAMES or time.monotonic() - quiet_since > 2.0):
                break
    finally:
        procs.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    return {s: (spots[s], truth[s]) for s in spots if s in truth}, diag


def streak_errors(frames):
    """
    Position errors [px] of bright, unflagged-edge streak spots vs their star's mid-exposure truth.

    Also the spots' flags and their streak lengths.
    """
    errors, flags, lengths = [], [], []
    for rec, t in frames.values():
        stars = t[t["kind"] == 0]
        bright = (rec["snr"] > 50) & ((rec["flags"] & 2) == 0)
        for spot in rec[bright]:
            d = np.hypot(stars["pixel_x"] - spot["x"], stars["pixel_y"] - spot["y"])
            if d.min() < 3.0:
                errors.append(d.min())
                flags.append(int(spot["flags"]))
                lengths.append(float(spot["streak_length"]))
    return np.array(errors), np.array(flags), np.array(lengths)


@pytest.mark.integration
def test_centroider_measures_streaks_at_mid_exposure_with_and_without_the_rate(tmp_path, monkeypatch):
    expected_length = np.hypot(*np.radians(RATE_DEG_S[:2])) * 0.1 * (512 / np.tan(np.radians(7.5)))

    # Rate aid from a gyro-like topic: the simulator's true rate remapped onto angular_velocity.
    frames, diag = run_pipeline(tmp_path / "aided", monkeypatch, {"exposure_time_s": 0.1, "rate_source": "topic"},
                                remaps={"centroider": {"angular_velocity": "truth/angular_velocity"}})
    assert len(frames) >= FRAMES - 2  # best effort: an early spots message may precede discovery
    assert int(diag["frames_rate_aided"]) >= FRAMES - 2  # the first frame may precede the first rate
    # Frames that had a rate (the first one or two can precede the first rate message).
    aided_frames = {k: v for k, v in frames.items() if np.any(v[0]["flags"] & FLAG_RATE_AIDED)}
    assert len(aided_frames) >= FRAMES - 3
    errors, flags, lengths = streak_errors(aided_frames)
    assert errors.size >= 50
    aided = (flags & FLAG_RATE_AIDED) != 0
    assert aided.mean() > 0.9 and np.all(flags[aided] & FLAG_STREAK)
    assert np.sqrt(np.mean(errors[aided] ** 2)) < 0.15
    assert abs(np.median(lengths[aided]) / expected_length - 1) < 0.03

    # No rate: the free streak fit still finds the mid-exposure positions and the length.
    frames, diag = run_pipeline(tmp_path / "free", monkeypatch, {"rate_source": "none"})
    assert int(diag.get("frames_rate_aided", 0)) == 0
    errors, flags, lengths = streak_errors(frames)
    assert errors.size >= 50 and np.all(flags & FLAG_RATE_AIDED == 0)
    streak = (flags & FLAG_STREAK) != 0
    assert streak.mean() > 0.8
    assert np.sqrt(np.mean(errors[streak] ** 2)) < 0.15
    assert abs(np.median(lengths[streak]) / expected_length - 1) < 0.05


@pytest.mark.integration
def test_centroider_estimates_the_psf_and_reports_it(tmp_path, monkeypatch):
    """
    A camera with a 0.6 px PSF at rest and the centroider at its defaults (prior 1 px).

    The running estimate on /diagnostics is the camera's width, from many stars; streaked
    frames without a rate (no round stars) report the width across the streaks' own tracks,
    the camera's 1 px (streak.own_tracks), not the streaks' length as a wide star.
    """
    frames, diag = run_pipeline(tmp_path / "sharp", monkeypatch, {"rate_source": "none"},
                                camera_params={"attitude.body_rate_deg_s": [0.0, 0.0, 0.0],
                                               "optics.psf_sigma_px": 0.6})
    assert diag["psf_source"] == "estimated" and diag["psf_reason"] == "-"
    assert float(diag["psf_sigma_px"]) == pytest.approx(0.6, rel=0.05)
    assert int(diag["psf_stars"]) >= 5 and float(diag["psf_sigma_uncertainty_px"]) < 0.03
    assert float(diag["psf_elongation"]) < 1.2
    assert diag["psf_fit_model"] == "gaussian"  # our simulator's PSF is a Gaussian
    frames, diag = run_pipeline(tmp_path / "streaks", monkeypatch, {"rate_source": "none"})
    assert diag["psf_source"] == "estimated" and diag["psf_reason"] == "-"
    assert float(diag["psf_sigma_px"]) == pytest.approx(1.0, rel=0.1)
