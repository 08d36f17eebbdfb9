# SPDX-License-Identifier: Apache-2.0
"""
The nodes as managed (lifecycle) nodes over DDS, driven through their lifecycle_msgs services as `ros2 lifecycle` does.

autostart false leaves them unconfigured; a transition the state does not offer is refused and
the node carries on; deactivate -> activate keeps the identifier's database (no reload); input
while inactive is ignored and counted; cleanup and shutdown end cleanly; ~/reset forces
lost-in-space. Real node processes, no ROS mocks.
"""
from __future__ import annotations

import time

import pytest
pytestmark = pytest.mark.slow  # every test here starts node processes

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import QuaternionStamped  # noqa: E402
from rclpy.qos import qos_profile_sensor_data as SENSOR_QOS  # noqa: E402
from sensor_msgs.msg import CameraInfo, PointCloud2  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from conftest import join_isolated_ros_domain, spots_at  # noqa: E402
from service_calls import answered  # noqa: E402
from star_tracker.models.attitude import radec_roll_to_matrix  # noqa: E402
from star_tracker.ros import convert  # noqa: E402
from star_tracker.ros.identifier_parameters import epoch_from_clock  # noqa: E402
from star_tracker.ros.pipeline import NodeProcesses, TrackerMonitor  # noqa: E402
from star_tracker.ros.qos import RESULT_QOS  # noqa: E402


class IdentifierDriver:
    """
    This test's side of an identifier.

    camera_info and spots publishers, attitude and /diagnostics subscriptions, a ~/reset
    client.
    """

    def __init__(self, spots):
        self.node = rclpy.create_node("lifecycle_driver")
        self.attitudes: list[int] = []  # stamps [ns]
        self.diagnostics: dict[str, str] = {}
        self.node.create_subscription(QuaternionStamped, "attitude",
                                      lambda m: self.attitudes.append(convert.stamp_to_ns(m.header.stamp)), RESULT_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.pub_info = self.node.create_publisher(CameraInfo, "camera_info", SENSOR_QOS)
        self.pub_spots = self.node.create_publisher(PointCloud2, "spots", SENSOR_QOS)
        self.reset_client = self.node.create_client(Trigger, "/identifier/reset")
        self.spots = spots
        self.stamp_ns = 1_000_000_000
        self.diagnostics_stamp_ns = 0  # header stamp of the latest identifier status [ns, wall clock]

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith("/identifier"):
                self.diagnostics = {kv.key: kv.value for kv in status.values}
                self.diagnostics_stamp_ns = convert.stamp_to_ns(msg.header.stamp)

    def spin(self, seconds: float, until=lambda: False) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            rclpy.spin_once(self.node, timeout_sec=0.05)
        return until()

    def fresh_diagnostics(self) -> dict[str, str]:
        """
        Return the identifier's /diagnostics published after this call (1 Hz).

        Judged by the message's own stamp: messages queued while the test did not spin (a
        lifecycle call) arrive first and describe the node before it.
        """
        called_ns = time.time_ns()
        assert self.spin(10.0, until=lambda: self.diagnostics_stamp_ns > called_ns), \
            "no /diagnostics from the identifier"
        return self.diagnostics

    def connect(self, camera) -> None:
        assert self.spin(30.0, until=lambda: self.pub_spots.get_subscription_count() > 0
                         and self.pub_info.get_subscription_count() > 0)
        for _ in range(3):  # best effort: repeat camera_info until the node has it
            self.pub_info.publish(convert.camera_to_info(camera, 1, "star_tracker_optical"))
            self.spin(0.3)

    def send_frames(self, n: int, answered: bool) -> list[int]:
        """
        Publish n spots frames 0.1 s apart in stamp, one at a time.

        Each waits for its attitude (answered) or 0.4 s (not expected to be answered).
        Returns their stamps.
        """
        stamps = []
        for _ in range(n):
            self.stamp_ns += 100_000_000
            stamp = self.stamp_ns
            stamps.append(stamp)
            self.pub_spots.publish(convert.spots_to_cloud(self.spots, stamp, "star_tracker_optical"))
            if answered:
                assert self.spin(20.0, until=lambda: stamp in self.attitudes), (stamp, self.attitudes)
            else:
                self.spin(0.4)
        return stamps

    def reset(self) -> Trigger.Response:
        """Call ~/reset, sent again if its answer is lost (service_calls.answered; a reset is idempotent)."""
        assert self.reset_client.wait_for_service(timeout_sec=10.0)
        return answered(self.node, lambda: self.reset_client.call_async(Trigger.Request()))


DOMAIN = 206  # 206-209: this file's private ROS domains


def counter(values: dict[str, str], key: str) -> int:
    return int(values.get(key, "0"))


@pytest.mark.integration
def test_identifier_lifecycle_round_trip_keeps_its_database(monkeypatch, tmp_path, catalog, nominal_camera,
                                                            database):
    env = join_isolated_ros_domain(monkeypatch, DOMAIN)
    good = spots_at(catalog.brighter_than(6.8).at_epoch(2026.0), nominal_camera, radec_roll_to_matrix(2.0, -0.4, 1.0))
    driver = IdentifierDriver(good)
    nodes = NodeProcesses(env, tmp_path / "logs", params={"identifier": {"autostart": False}}, nodes=("identifier",))
    try:
        nodes.start().wait_ready()  # ~/get_state answers: unconfigured
        assert nodes.get_state("identifier") == "unconfigured"
        values = driver.fresh_diagnostics()  # published in every state
        assert values["lifecycle_state"] == "unconfigured" and "database_loads" not in values, values
        assert driver.reset().success is False  # nothing to reset yet

        # A transition this state does not offer: refused, counted, nothing changes.
        assert nodes.change_state("identifier", "activate") is False
        assert nodes.change_state("identifier", "deactivate") is False
        assert nodes.get_state("identifier") == "unconfigured"
        assert counter(driver.fresh_diagnostics(), "transitions_refused") == 2

        assert nodes.change_state("identifier", "configure") is True
        assert nodes.get_state("identifier") == "inactive"
        driver.connect(nominal_camera)
        driver.send_frames(2, answered=False)  # configured but inactive: ignored, counted
        values = driver.fresh_diagnostics()
        ignored = counter(values, "frames_ignored_inactive")
        assert driver.attitudes == [] and ignored >= 1, values  # best effort: at least one arrived
        assert values["lifecycle_state"] == "inactive" and counter(values, "database_loads") == 1, values

        assert nodes.change_state("identifier", "activate") is True
        driver.send_frames(3, answered=True)

        assert nodes.change_state("identifier", "deactivate") is True
        quiet = driver.send_frames(3, answered=False)
        driver.spin(1.0)
        values = driver.fresh_diagnostics()
        assert not set(quiet) & set(driver.attitudes), driver.attitudes
        assert counter(values, "frames_ignored_inactive") > ignored and values["lifecycle_state"] == "inactive", values

        assert nodes.change_state("identifier", "activate") is True
        driver.send_frames(3, answered=True)
        values = driver.fresh_diagnostics()
        assert counter(values, "database_loads") == 1, values  # the round trip did not reload it
        assert values["lifecycle_state"] == "active", values

        assert nodes.change_state("identifier", "cleanup") is False  # active: deactivate first
        assert nodes.change_state("identifier", "deactivate") is True
        assert nodes.change_state("identifier", "cleanup") is True
        assert nodes.get_state("identifier") == "unconfigured"
        assert driver.reset().success is False  # the database and tracker are released
        assert nodes.change_state("identifier", "shutdown") is True
        code = nodes.processes["identifier"].wait(timeout=30)  # a finalized node ends its process
    finally:
        codes = nodes.stop()
        driver.node.destroy_node()
        rclpy.try_shutdown()
    log = nodes.log_paths["identifier"].read_text()
    assert code == 0 and codes == {"identifier": 0}, log
    assert log.count("guide stars to Hp") == 1, log  # one database load in the whole round trip
    # The shipped database.epoch_jyear (0): the guide stars at the clock's date, as the simulator renders them.
    assert any(f"at epoch {epoch_from_clock(0.0, time.time() - ago):g}," in log for ago in (0.0, 600.0)), log
    assert "transition 'activate' refused in state unconfigured" in log, log


@pytest.mark.integration
def test_reset_drops_tracking_and_the_next_frame_is_lost_in_space(monkeypatch, tmp_path, catalog, nominal_camera,
                                                                  database):
    env = join_isolated_ros_domain(monkeypatch, DOMAIN + 1)
    good = spots_at(catalog.brighter_than(6.8).at_epoch(2026.0), nominal_camera, radec_roll_to_matrix(2.0, -0.4, 1.0))
    driver = IdentifierDriver(good)
    nodes = NodeProcesses(env, tmp_path / "logs", nodes=("identifier",))
    try:
        nodes.start().wait_ready()  # autostart: active
        assert nodes.get_state("identifier") == "active"
        driver.connect(nominal_camera)
        driver.send_frames(4, answered=True)
        before = driver.fresh_diagnostics()
        assert counter(before, "frames_lost_in_space") == 1 and counter(before, "frames_tracking") == 3, before
        assert before["mode"] == "tracking", before

        response = driver.reset()
        assert response.success is True and "lost-in-space" in response.message, response
        assert counter(driver.fresh_diagnostics(), "resets") == 1

        driver.send_frames(1, answered=True)
        after = driver.fresh_diagnostics()
        assert counter(after, "frames_lost_in_space") == 2 and counter(after, "frames_tracking") == 3, after
        assert after["mode"] == "lost_in_space", after
        driver.send_frames(1, answered=True)  # and tracking resumes from that solution
        assert counter(driver.fresh_diagnostics(), "frames_tracking") == 4, driver.diagnostics
    finally:
        codes = nodes.stop()
        driver.node.destroy_node()
        rclpy.try_shutdown()
    assert codes == {"identifier": 0}, nodes.log_paths["identifier"].read_text()


@pytest.mark.integration
def test_pipeline_driven_through_the_lifecycle_services(monkeypatch, tmp_path):
    """
    All three nodes with autostart false.

    Configured and activated over ~/change_state (the camera last), attitudes flow; the camera
    deactivated publishes nothing, activated again it resumes its time line (skipped frames
    counted) and attitudes flow again.
    """
    env = join_isolated_ros_domain(monkeypatch, DOMAIN + 2)
    params = {name: {"autostart": False} for name in ("camera_simulator", "centroider", "identifier")}
    params["camera_simulator"].update({"rate_hz": 2.0})
    monitor = TrackerMonitor(name="lifecycle_monitor")
    nodes = NodeProcesses(env, tmp_path / "logs", params=params)
    try:
        nodes.start().wait_ready()
        assert {name: nodes.get_state(name) for name in params} == dict.fromkeys(params, "unconfigured")
        for name in ("centroider", "identifier", "camera_simulator"):
            assert nodes.change_state(name, "configure") is True, name
            assert nodes.change_state(name, "activate") is True, name
        assert monitor.spin_for(60.0, until=lambda: sum(f.attitude is not None for f in monitor.frames.values()) >= 3)

        assert nodes.change_state("camera_simulator", "deactivate") is True
        monitor.spin_for(0.5)  # what was in flight
        seen = len(monitor.frames)
        monitor.spin_for(2.0)
        assert len(monitor.frames) == seen  # nothing published while inactive

        assert nodes.change_state("camera_simulator", "activate") is True
        identified = sum(f.attitude is not None for f in monitor.frames.values())
        assert monitor.spin_for(60.0, until=lambda: sum(f.attitude is not None for f in monitor.frames.values())
                                >= identified + 3)
        monitor.spin_for(1.5)
        camera = monitor.diagnostics.get("star_tracker/camera_simulator", {})
        assert camera.get("lifecycle_state") == "active", camera
        assert int(camera.get("frames_skipped_inactive", "0")) >= 1, camera
        stamps = sorted(monitor.frames)
        assert all(b > a for a, b in zip(stamps, stamps[1:]))
        # The shutdown transition releases the truth publishers: their last messages are
        # acknowledged first (output_flush.py), the monitor being a reliable truth subscriber.
        assert nodes.change_state("camera_simulator", "shutdown") is True
    finally:
        codes = nodes.stop()
        monitor.destroy_node()
        rclpy.try_shutdown()
    assert codes == dict.fromkeys(params, 0), {name: nodes.log_paths[name].read_text() for name in params}
    camera_log = nodes.log_paths["camera_simulator"].read_text()
    assert "outputs flushed: every subscriber acknowledged truth/attitude" in camera_log, camera_log


@pytest.mark.integration
def test_a_failed_configure_leaves_the_node_unconfigured_and_running(monkeypatch, tmp_path, catalog, nominal_camera):
    """
    Start with autostart false and an unknown algorithm.

    Configure fails with the reason in the log and `transitions_failed` counted; the node stays
    unconfigured and still answers; shutdown ends it.
    """
    env = join_isolated_ros_domain(monkeypatch, DOMAIN + 3)
    driver = IdentifierDriver(spots=None)
    params = {"identifier": {"autostart": False, "algorithm": "guesswork"}}
    nodes = NodeProcesses(env, tmp_path / "logs", params=params, nodes=("identifier",))
    try:
        nodes.start().wait_ready()
        assert nodes.change_state("identifier", "configure") is False
        assert nodes.get_state("identifier") == "unconfigured"
        values = driver.fresh_diagnostics()
        assert counter(values, "transitions_failed") == 1 and values["lifecycle_state"] == "unconfigured", values
        assert nodes.change_state("identifier", "shutdown") is True
        code = nodes.processes["identifier"].wait(timeout=30)
    finally:
        nodes.stop()
        driver.node.destroy_node()
        rclpy.try_shutdown()
    log = nodes.log_paths["identifier"].read_text()
    assert code == 0, log
    assert "on_configure failed: ValueError: unknown identification algorithm 'guesswork'" in log, log
    assert "Traceback" not in log, log
