# SPDX-License-Identifier: Apache-2.0
"""
The identifier node over DDS, driven by this test's own publisher.

It publishes only verified attitudes, explains failures on /diagnostics, and survives bad
input.
"""
from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest
pytestmark = pytest.mark.slow  # every test here starts processes (nodes or node executables)

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import QuaternionStamped  # noqa: E402
from sensor_msgs.msg import CameraInfo, PointCloud2  # noqa: E402

from star_tracker.models.attitude import attitude_error, quaternion_to_matrix, radec_roll_to_matrix  # noqa: E402
from star_tracker.centroid import Spots  # noqa: E402
from star_tracker.ros import convert  # noqa: E402
from rclpy.qos import qos_profile_sensor_data as SENSOR_QOS  # noqa: E402  (what a generic user subscribes with)

from star_tracker.ros.qos import RESULT_QOS  # noqa: E402
from conftest import join_isolated_ros_domain, spots_at  # noqa: E402
from star_tracker.ros.pipeline import NodeProcesses, isolated_ros_environment  # noqa: E402

ARCSEC = np.radians(1 / 3600)


@pytest.mark.integration
def test_identifier_node_publishes_only_verified_attitudes(monkeypatch, tmp_path, catalog, nominal_camera, database):
    env = join_isolated_ros_domain(monkeypatch)
    node = rclpy.create_node("identifier_driver")
    attitudes, diagnostics = [], []
    node.create_subscription(QuaternionStamped, "attitude", attitudes.append, RESULT_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: diagnostics.extend(s for s in m.status if s.name.endswith("/identifier")), 10)
    pub_info = node.create_publisher(CameraInfo, "camera_info", SENSOR_QOS)
    pub_spots = node.create_publisher(PointCloud2, "spots", SENSOR_QOS)
    processes = NodeProcesses(env, tmp_path / "logs", nodes=("identifier",)).start()

    def spin(seconds, until=lambda: False):
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            rclpy.spin_once(node, timeout_sec=0.05)

    try:
        processes.wait_ready()
        spin(30.0, until=lambda: pub_spots.get_subscription_count() > 0 and pub_info.get_subscription_count() > 0)
        rng = np.random.default_rng(21)
        truth = radec_roll_to_matrix(2.0, -0.4, 1.0)
        good = spots_at(catalog.brighter_than(6.8).at_epoch(2026.0), nominal_camera, truth)
        n = 30
        random_spots = Spots(rng.uniform(0, 1023, n), rng.uniform(0, 1023, n), rng.uniform(1, 1e3, n), np.full(n, 30.0),
                             np.tile(np.eye(2) * 0.01, (n, 1, 1)), np.zeros(n, np.uint32), np.ones(n, np.int32),
                             np.ones(n), 1024, 1024)
        malformed = PointCloud2(height=1, width=2, point_step=12, data=b"\x00" * 24)
        for _ in range(3):  # best effort: repeat camera_info until the node has it
            pub_info.publish(convert.camera_to_info(nominal_camera, 1, "star_tracker_optical"))
            spin(0.3)
        stamps = {"random": 1_000_000_000, "malformed": 1_100_000_000, "good": 1_200_000_000}
        pub_spots.publish(convert.spots_to_cloud(random_spots, stamps["random"], "star_tracker_optical"))
        spin(0.5)
        malformed.header.stamp = convert.ns_to_stamp(stamps["malformed"])
        pub_spots.publish(malformed)
        spin(0.5)
        pub_spots.publish(convert.spots_to_cloud(good, stamps["good"], "star_tracker_optical"))
        spin(10.0,
             until=lambda: attitudes and any("frames_identified" in [kv.key for kv in s.values] for s in diagnostics))
        spin(1.5)
    finally:
        codes = processes.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    log = (tmp_path / "logs" / "identifier.log").read_text()
    assert codes == {"identifier": 0}, log
    # Only the good frame produced an attitude, with its stamp unchanged, and it is right.
    assert [convert.stamp_to_ns(a.header.stamp) for a in attitudes] == [stamps["good"]], log
    estimate = quaternion_to_matrix(convert.quaternion_from_msg(attitudes[0]))
    assert attitude_error(estimate, truth)[0] < 2 * ARCSEC
    # The failures were explained: in the log and counted on /diagnostics.
    assert "not identified" in log and "rejected spots message" in log
    counters = {kv.key: kv.value for kv in diagnostics[-1].values}
    assert counters.get("frames_rejected") == "1" and counters.get("frames_identified") == "1"
    assert counters.get("not_identified_no_match", "0") == "1" or counters.get("not_identified_timeout", "0") == "1"


@pytest.mark.parametrize("module, args, message", [
    ("camera_simulator_node", ["-p", "rate_hz:=-5.0"], "rate_hz"),
    ("camera_simulator_node", ["-p", "sensor.exposure_s:=0.5"], "longer than the frame period"),
    ("identifier_node", ["-p", "algorithm:=guesswork"], "unknown identification algorithm"),
    ("centroider_node", ["-p", "min_area:=9", "-p", "max_area:=3"], "min_area"),
])
def test_bad_parameters_stop_startup_with_a_clear_error(module, args, message):
    env = isolated_ros_environment()
    result = subprocess.run([sys.executable, "-m", f"star_tracker.ros.{module}", "--ros-args", *args],
                            env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stdout + result.stderr
    assert message in result.stderr and "Traceback" not in result.stderr


@pytest.mark.integration
def test_online_calibration_reports_the_drifted_focal_length_on_diagnostics(monkeypatch, tmp_path, catalog,
                                                                            nominal_camera, database):
    """
    Check calibration.enabled with a drifted camera.

    Spots of a camera whose focal length drifted 0.1 % (and k1 = 0.01) from the camera_info;
    after frames_per_fit published frames /diagnostics carries the fit.
    """
    from star_tracker.models.camera import CameraModel

    env = join_isolated_ros_domain(monkeypatch)
    node = rclpy.create_node("calibration_driver")
    diagnostics = []
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: diagnostics.extend(s for s in m.status if s.name.endswith("/identifier")), 10)
    pub_info = node.create_publisher(CameraInfo, "camera_info", SENSOR_QOS)
    pub_spots = node.create_publisher(PointCloud2, "spots", SENSOR_QOS)
    params = {"identifier": {"calibration.enabled": True, "calibration.frames_per_fit": 3}}
    processes = NodeProcesses(env, tmp_path / "logs", params=params, nodes=("identifier",)).start()
    drifted = CameraModel(1024, 1024, nominal_camera.fx * 1.001, nominal_camera.fy * 1.001, nominal_camera.cx,
                          nominal_camera.cy, (0.01, 0.0, 0.0, 0.0, 0.0))
    good = spots_at(catalog.brighter_than(6.8).at_epoch(2026.0), drifted, radec_roll_to_matrix(2.0, -0.4, 1.0))

    def spin(seconds, until=lambda: False):
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            rclpy.spin_once(node, timeout_sec=0.05)

    def fitted():
        return any(kv.key == "calibration_fits" for s in diagnostics for kv in s.values)

    try:
        processes.wait_ready()
        spin(30.0, until=lambda: pub_spots.get_subscription_count() > 0 and pub_info.get_subscription_count() > 0)
        for _ in range(3):
            pub_info.publish(convert.camera_to_info(nominal_camera, 1, "star_tracker_optical"))
            spin(0.3)
        for k in range(4):
            pub_spots.publish(convert.spots_to_cloud(good, 1_000_000_000 + k * 100_000_000, "star_tracker_optical"))
            spin(3.0, until=fitted)
        spin(10.0, until=fitted)
        spin(1.5)
    finally:
        codes = processes.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    log = (tmp_path / "logs" / "identifier.log").read_text()
    assert codes == {"identifier": 0}, log
    values = {kv.key: kv.value for kv in diagnostics[-1].values}
    assert values.get("calibration_fits") == "1", values
    focal, sigma = float(values["calibration_focal_px"]), float(values["calibration_focal_sigma_px"])
    assert abs(focal - drifted.fx) <= 3 * sigma + 1e-3 and abs(focal - nominal_camera.fx) > 3 * sigma, values
    # Noise-free spots: the solver's convergence tolerance (~1e-5 in k1), not noise, bounds the error.
    assert abs(float(values["calibration_k1"]) - 0.01) <= 3 * float(values["calibration_k1_sigma"]) + 1e-5, values
    assert values["calibration_applied"] in ("f", "k1", "f,k1"), values
