# SPDX-License-Identifier: Apache-2.0
"""
Bad input through the real nodes (separate processes, Fast DDS, isolated domain).

Each node is fed a sequence of bad messages and bad parameter changes, then a good message.
Each bad input must show up as a counter on /diagnostics and a log line, the node must keep
running and process the good message, and nothing may end in a traceback. No ROS mocks.
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
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped  # noqa: E402
from rclpy.parameter import Parameter, parameter_value_to_python  # noqa: E402
from rclpy.qos import qos_profile_sensor_data as SENSOR_QOS  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2  # noqa: E402

from star_tracker.models.attitude import attitude_error, quaternion_to_matrix, radec_roll_to_matrix  # noqa: E402
from star_tracker.models.camera import CameraModel  # noqa: E402
from star_tracker.centroid import Spots  # noqa: E402
from star_tracker.sim.motion import ConstantRateMotion  # noqa: E402
from star_tracker.sim.render import StarFieldRenderer  # noqa: E402
from star_tracker.sim.sensor import SensorModel  # noqa: E402
from star_tracker.ros import convert  # noqa: E402
from star_tracker.ros.qos import RESULT_QOS  # noqa: E402
from star_tracker.ros.pipeline import NodeProcesses, isolated_ros_environment  # noqa: E402
from conftest import spots_at  # noqa: E402  one star-spot builder for the tests
from service_calls import answered, primed_parameter_client  # noqa: E402
from test_integration import ros_graph  # noqa: E402,F401  the isolated-domain fixture

ARCSEC = np.radians(1 / 3600)
FRAME = "star_tracker_optical"


class Driver:
    """This test's own node: publishes bad input, records outputs and the node's diagnostics."""

    def __init__(self, watched: str):
        self.node = rclpy.create_node(f"{watched}_driver")
        self.watched = watched
        self.counters: dict[str, str] = {}
        self.clients: dict = {}  # node name -> its primed parameter client
        self.messages: list[str] = []
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith("/" + self.watched):
                self.counters = {kv.key: kv.value for kv in status.values}
                self.messages.append(status.message)

    def count(self, key: str) -> int:
        return int(self.counters.get(key, 0))

    def spin(self, seconds: float, until=lambda: False) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(self.node, timeout_sec=0.02)
            if until():
                return True
        return until()

    def parameter_client(self, node_name: str):
        """Return this driver's parameter client on `node_name`, each service answered once (no answer lost)."""
        if node_name not in self.clients:
            self.clients[node_name] = primed_parameter_client(self.node, node_name)
        return self.clients[node_name]

    def set_parameters(self, node_name: str, **values):
        """set_parameters on the node under test: list of (successful, reason)."""
        future = self.parameter_client(node_name).set_parameters(
            [Parameter(k.replace("__", "."), value=v) for k, v in values.items()])
        assert self.spin(20.0, until=future.done), f"{node_name} did not answer set_parameters"
        return [(r.successful, r.reason) for r in future.result().results]

    def get_parameter(self, node_name: str, name: str):
        client = self.parameter_client(node_name)
        return parameter_value_to_python(answered(self.node, lambda: client.get_parameters([name])).values[0])


def now_ns() -> int:
    return time.time_ns()


def stamped(msg, stamp_ns: int):
    msg.header.stamp = convert.ns_to_stamp(stamp_ns)
    msg.header.frame_id = FRAME
    return msg


# ------------------------------------------------------------------------------ centroider
@pytest.mark.integration
def test_centroider_survives_bad_images_info_rates_and_parameters(ros_graph,  # noqa: F811  the fixture
                                                                  tmp_path, catalog):
    camera = CameraModel.from_fov(256, 256, np.radians(4.0))
    renderer = StarFieldRenderer(camera, SensorModel(), catalog.at_epoch(2026.0), magnitude_limit=8.5)
    good_image = renderer.render(ConstantRateMotion(radec_roll_to_matrix(1.5, 0.3, 0.0), np.zeros(3)), 1.0, 7).image

    driver = Driver("centroider")
    spots: dict[int, int] = {}
    last_answer = [time.monotonic()]

    def on_spots(msg):
        spots[convert.stamp_to_ns(msg.header.stamp)] = msg.width * msg.height
        last_answer[0] = time.monotonic()
    driver.node.create_subscription(PointCloud2, "spots", on_spots, SENSOR_QOS)
    pub_image = driver.node.create_publisher(Image, "image_raw", SENSOR_QOS)
    pub_info = driver.node.create_publisher(CameraInfo, "camera_info", SENSOR_QOS)
    pub_rate = driver.node.create_publisher(Vector3Stamped, "angular_velocity", RESULT_QOS)
    # Bad input, not overload: a queue deep enough that a host stall drops none of the frames counted below.
    nodes = NodeProcesses(ros_graph, tmp_path / "logs", {"centroider": {"detection_sigmaa": 3.0, "queue_depth": 50}},
                          nodes=("centroider",))
    try:
        nodes.start()
        nodes.wait_ready()
        assert driver.spin(20.0, until=lambda: pub_image.get_subscription_count() > 0
                           and pub_info.get_subscription_count() > 0 and pub_rate.get_subscription_count() > 0)
        base = now_ns() - 10 * 10**9
        # A first good frame, answered: the best-effort path is up before anything counts. The
        # first frame can take many seconds on a loaded host (kernels loading): copies are sent
        # every 2 s until one is answered.
        for _ in range(60):
            pub_image.publish(stamped(convert.array_to_image(good_image, 0, FRAME), base - 10**9))
            if driver.spin(2.0, until=lambda: base - 10**9 in spots):
                break
        # Every copy received is processed before counting starts: the centroider has been quiet
        # for 3 s and its diagnostics show as many frames processed as received.
        driver.spin(90.0, until=lambda: time.monotonic() - last_answer[0] > 3.0 and driver.count("frames_received") > 0
                    and driver.count("frames_processed") == driver.count("frames_received"))
        baseline = dict(driver.counters)
        delta = lambda key: driver.count(key) - int(baseline.get(key, 0))  # noqa: E731

        def send(msg, stamp_ns, publisher=pub_image):
            publisher.publish(stamped(msg, stamp_ns))
            driver.spin(0.15)

        def image(array, k):
            return convert.array_to_image(array, 0, FRAME), base + k * 100_000_000

        # Undecodable images: no spots, frames_rejected.
        wrong_encoding = Image(height=4, width=4, encoding="rgb8", step=12, data=bytes(48))
        short_data = Image(height=4, width=4, encoding="mono16", step=8, data=bytes(31))
        empty = Image(height=0, width=0, encoding="mono16", step=0)
        enormous = Image(height=65536, width=65536, encoding="mono8", step=65536, data=bytes(16))
        for k, msg in enumerate((wrong_encoding, short_data, empty, enormous)):
            send(msg, base + k * 100_000_000)
        # Bad camera_info (the good one comes with the good frame), a NaN rate.
        for k in ([np.nan] * 9, [0.0] * 9, [-500.0, 0, 128, 0, -500.0, 128, 0, 0, 1]):
            info = convert.camera_to_info(camera, 0, FRAME)
            info.k = [float(v) for v in k]
            send(info, base, pub_info)
        rate = convert.vector3_msg(np.array([np.nan, 0.0, 0.0]), base, FRAME)
        send(rate, base, pub_rate)
        # Decodable but suspicious: still measured and published, and counted.
        send(*image(np.zeros((256, 256), np.uint16), 5))  # all black
        send(*image(np.full((256, 256), 65535, np.uint16), 6))  # all saturated
        send(convert.array_to_image(good_image, 0, FRAME), now_ns() + 100 * 10**9)  # from the future
        send(*image(good_image, 3))  # older than frame 6: out of order
        send(convert.array_to_image(good_image, 0, FRAME), 0)  # unstamped
        # Runtime parameters: out of range, inconsistent together, read-only; then a good one.
        refused = driver.set_parameters("centroider", detection_sigma=0.5)
        refused += driver.set_parameters("centroider", max_area=1)  # < min_area (2)
        refused += driver.set_parameters("centroider", queue_depth=5)
        refused += driver.set_parameters("centroider", rate_source="gyro")  # runtime, but not a source
        accepted = driver.set_parameters("centroider", detection_sigma=5.0)
        # The good frame, with a good camera_info.
        send(convert.camera_to_info(camera, 0, FRAME), base, pub_info)
        good_ns = base + 20 * 100_000_000
        send(convert.array_to_image(good_image, 0, FRAME), good_ns)
        expected = {"frames_rejected": 4, "camera_info_rejected": 3, "rates_rejected": 1, "frames_no_signal": 1,
                    "frames_saturated": 1, "frames_from_future": 1, "frames_out_of_order": 1,
                    "frames_unstamped": 1, "parameter_changes_rejected": 4, "frames_processed": 6}
        driver.spin(15.0, until=lambda: all(delta(k) >= v for k, v in expected.items()) and good_ns in spots)
        detection_sigma = driver.get_parameter("centroider", "detection_sigma")
        max_area = driver.get_parameter("centroider", "max_area")
    finally:
        codes = nodes.stop()
        driver.node.destroy_node()
    log = (tmp_path / "logs" / "centroider.log").read_text()
    assert codes == {"centroider": 0}, log
    assert "Traceback" not in log, log
    assert {k: delta(k) for k in expected} == expected, (driver.counters, baseline, log)
    assert spots.get(good_ns, 0) >= 5, (spots, log)  # the good frame after all that
    assert len(spots) == 7  # first, black, saturated, future, out-of-order, unstamped, good: nothing else
    # Refused with a reason, old values kept; the good change applied.
    assert [ok for ok, _ in refused] == [False, False, False, False]
    assert "outside" in refused[0][1] or "out of range" in refused[0][1]
    assert "min_area" in refused[1][1] and "read-only" in refused[2][1] and "rate_source" in refused[3][1]
    assert accepted == [(True, "")] and detection_sigma == 5.0 and max_area == 20000
    # One clear log line per kind of problem.
    for text in ("unsupported image encoding", "data size", "empty image", "pixel limit", "rejected camera_info",
                 "non-finite values", "frame without signal", "saturated frame", "from future", "out of order",
                 "is unstamped",
                 "parameter change refused", "ignored unknown parameter(s): detection_sigmaa"):
        assert text in log, text


# ------------------------------------------------------------------------------ identifier
def with_garbage(spots: Spots) -> Spots:
    """
    Return `spots` plus bad ones: NaN, infinite, far-away, absurdly uncertain, a duplicate.

    The duplicate is a second copy of the brightest (9 in all; a coincident pair used to crash the hybrid
    identifier).
    """
    nan, inf = np.nan, np.inf
    x = np.array([nan, 10.0, inf, 20.0, 1e9, 30.0, 40.0, -inf])
    y = np.array([5.0, nan, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0])
    flux = np.array([1e6, 1e6, 1e6, nan, 1e6, 1e6, 1e6, 1e6])
    cov = np.tile(np.eye(2) * 0.01, (8, 1, 1))
    cov[5] = np.eye(2) * inf
    cov[6] = np.eye(2) * 1e12
    n = 8
    junk = Spots(x, y, flux, np.full(n, 50.0), cov, np.zeros(n, np.uint32), np.ones(n, np.int32), np.ones(n),
                 spots.width, spots.height)
    merged = {f: np.concatenate([getattr(junk, f), getattr(spots, f), getattr(spots, f)[:1]]) for f in
              ("x", "y", "flux", "snr", "cov", "flags", "area", "peak", "streak_length", "streak_angle")}
    return Spots(**merged, width=spots.width, height=spots.height)


@pytest.mark.integration
def test_identifier_survives_bad_spots_stamps_info_and_parameters(ros_graph,  # noqa: F811  the fixture
                                                                  tmp_path, catalog, database):
    # A distorted lens: with it, an empty frame used to crash identify() (camera.pixel_to_ray).
    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0), (-0.05, 0.0, 0.0, 0.0, 0.0))
    sky = catalog.brighter_than(6.8).at_epoch(2026.0)
    truth = radec_roll_to_matrix(2.0, -0.4, 1.0)
    good = spots_at(sky, camera, truth)

    driver = Driver("identifier")
    attitudes: list[QuaternionStamped] = []
    driver.node.create_subscription(QuaternionStamped, "attitude", attitudes.append, RESULT_QOS)
    pub_info = driver.node.create_publisher(CameraInfo, "camera_info", SENSOR_QOS)
    pub_spots = driver.node.create_publisher(PointCloud2, "spots", SENSOR_QOS)
    nodes = NodeProcesses(ros_graph, tmp_path / "logs", {"identifier": {"queue_depth": 50}}, nodes=("identifier",))
    try:
        nodes.start()
        nodes.wait_ready()
        assert driver.spin(20.0, until=lambda: pub_spots.get_subscription_count() > 0
                           and pub_info.get_subscription_count() > 0)
        base = now_ns() - 30 * 10**9
        ms = 1_000_000

        def send_spots(s: Spots | PointCloud2, stamp_ns: int, wait_for_attitude: bool = False):
            msg = s if isinstance(s, PointCloud2) else convert.spots_to_cloud(s, 0, FRAME)
            before = len(attitudes)
            pub_spots.publish(stamped(msg, stamp_ns))
            driver.spin(10.0 if wait_for_attitude else 0.2, until=lambda: wait_for_attitude and len(attitudes) > before)

        for attempt in range(10):  # before any camera_info (best effort: until one arrives)
            send_spots(good, base - (10 - attempt) * 100 * ms)
            if driver.spin(1.5, until=lambda: driver.count("frames_without_camera_info") > 0):
                break
        bad_infos_sent = 0
        for k, d in (([np.nan] * 9, [0.0] * 5), ([0.0] * 9, [0.0] * 5), (None, [-50.0, 0, 0, 0, 0])):
            info = convert.camera_to_info(camera, 0, FRAME)
            if k is not None:
                info.k = [float(v) for v in k]
            info.d = d
            rejected = driver.count("camera_info_rejected")
            for _ in range(5):  # best effort: again if a host stall lost it (the counter tells)
                pub_info.publish(stamped(info, base))
                bad_infos_sent += 1
                if driver.spin(3.0, until=lambda: driver.count("camera_info_rejected") > rejected):
                    break
        for _ in range(3):  # best effort: repeat the good one until the node has it
            pub_info.publish(stamped(convert.camera_to_info(camera, 0, FRAME), base))
            driver.spin(0.3)

        send_spots(with_garbage(good), base + 1000 * ms, wait_for_attitude=True)  # garbage dropped, stars identified
        send_spots(good, base + 500 * ms)  # out of order
        send_spots(good, base + 1000 * ms)  # duplicate stamp
        send_spots(good, 0)  # unstamped
        send_spots(good, now_ns() + 100 * 10**9)  # from the future
        send_spots(Spots.empty(1024, 1024), base + 1100 * ms)  # nothing to identify
        send_spots(PointCloud2(height=1, width=2, point_step=12, data=bytes(24)), base + 1200 * ms)  # malformed
        send_spots(good, base + 1300 * ms, wait_for_attitude=True)  # tracked
        send_spots(good, base - 10_000 * ms, wait_for_attitude=True)  # a replay restarted: track reset
        refused = driver.set_parameters("identifier", inline_wait_s=-1.0)
        refused += driver.set_parameters("identifier", **{"tracking__max_coast_s": 5.0})
        refused += driver.set_parameters("identifier", **{"stamp__max_future_s": float("nan")})
        accepted = driver.set_parameters("identifier", **{"stamp__max_future_s": 0.5})
        send_spots(good, base - 9_900 * ms, wait_for_attitude=True)  # the good frame after all that
        expected = {"camera_info_rejected": 3, "spots_dropped_invalid": 9,
                    "frames_out_of_order": 2, "frames_unstamped": 1, "frames_from_future": 1,
                    "not_identified_too_few_spots": 1, "frames_rejected": 1, "time_resets": 1,
                    "parameter_changes_rejected": 3, "frames_identified": 4}
        driver.spin(15.0, until=lambda: all(driver.count(k) >= v for k, v in expected.items()))
    finally:
        codes = nodes.stop()
        driver.node.destroy_node()
    log = (tmp_path / "logs" / "identifier.log").read_text()
    assert codes == {"identifier": 0}, log
    assert "Traceback" not in log and "frames_failed" not in driver.counters, log
    # Each bad camera_info rejected (a resent one counts again: the node cannot know it is a copy).
    assert 3 <= driver.count("camera_info_rejected") <= bad_infos_sent, (driver.counters, log)
    del expected["camera_info_rejected"]
    assert {k: driver.count(k) for k in expected} == expected, (driver.counters, log)
    assert driver.count("frames_without_camera_info") >= 1
    # Attitudes only for the good frames, in order, each right.
    stamps = [convert.stamp_to_ns(a.header.stamp) for a in attitudes]
    assert stamps == [base + 1000 * ms, base + 1300 * ms, base - 10_000 * ms, base - 9_900 * ms], log
    for msg in attitudes:
        assert attitude_error(quaternion_to_matrix(convert.quaternion_from_msg(msg)), truth)[2] < 5 * ARCSEC
    assert [ok for ok, _ in refused] == [False, False, False] and accepted == [(True, "")]
    assert "read-only" in refused[1][1]
    for text in ("before any valid camera_info", "rejected camera_info", "no usable field of view",
                 "dropped 9 spot(s)", "out of order", "unstamped", "from future", "not identified: no spots",
                 "rejected spots message", "track restarted", "parameter change refused"):
        assert text in log, text


# ------------------------------------------------------------------------------ camera simulator
@pytest.mark.integration
def test_camera_refuses_runtime_changes_and_bad_external_truth(ros_graph, tmp_path):  # noqa: F811  the fixture
    driver = Driver("camera_simulator")
    pub_q = driver.node.create_publisher(QuaternionStamped, "truth_in/attitude", RESULT_QOS)
    pub_w = driver.node.create_publisher(Vector3Stamped, "truth_in/angular_velocity", RESULT_QOS)
    images = []
    driver.node.create_subscription(Image, "image_raw", lambda m: images.append(convert.stamp_to_ns(m.header.stamp)),
                                    SENSOR_QOS)
    nodes = NodeProcesses(ros_graph, tmp_path / "logs", {"camera_simulator": {
        "attitude.profile": "external", "rate_hz": 5.0, "image.width": 256, "image.height": 256}},
        nodes=("camera_simulator",))
    try:
        nodes.start()
        nodes.wait_ready()
        assert driver.spin(20.0,
                           until=lambda: pub_q.get_subscription_count() > 0 and pub_w.get_subscription_count() > 0)
        refused = driver.set_parameters("camera_simulator", rate_hz=1000.0)
        refused += driver.set_parameters("camera_simulator", rate_hz=-1.0)
        rate_hz = driver.get_parameter("camera_simulator", "rate_hz")
        q = np.array([0.1, 0.2, 0.3, 0.9])
        t = now_ns()
        for quaternion, omega in (([np.nan, 0, 0, 1], [0.0, 0, 0]), ([0.0, 0, 0, 0], [0.0, 0, 0]),
                                  (list(q), [np.inf, 0, 0])):
            t += 10 * 1_000_000
            pub_q.publish(convert.quaternion_msg(np.array(quaternion, float), t))
            pub_w.publish(convert.vector3_msg(np.array(omega), t, FRAME))
            driver.spin(0.1)
        # Then good truth at 50 Hz for a while: frames come out.
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            t_now = now_ns()
            pub_q.publish(convert.quaternion_msg(q, t_now))
            pub_w.publish(convert.vector3_msg(np.zeros(3), t_now, FRAME))
            driver.spin(0.02)
        driver.spin(5.0,
                    until=lambda: driver.count("external_samples_rejected") >= 3 and driver.count("frames_published"))
    finally:
        codes = nodes.stop()
        driver.node.destroy_node()
    log = (tmp_path / "logs" / "camera_simulator.log").read_text()
    assert codes == {"camera_simulator": 0}, log
    assert "Traceback" not in log
    assert [ok for ok, _ in refused] == [False, False] and all("read-only" in why for _, why in refused)
    assert rate_hz == 5.0
    assert driver.count("parameter_changes_rejected") == 2 and "parameter change refused" in log
    assert driver.count("external_samples_rejected") == 3, driver.counters
    assert driver.count("frames_published") >= 3 and len(images) >= 3


# ------------------------------------------------------------------------------ startup
@pytest.mark.parametrize("module, args, env_extra, message", [
    ("centroider_node", ["-p", "detection_sigma"], {}, "Couldn't parse parameter override"),
    ("centroider_node", ["-p", "detection_sigma:=abc"], {}, "expecting type 'DOUBLE'"),
    ("centroider_node", ["-p", "detection_sigma:=.nan"], {}, "out of range"),
    ("centroider_node", ["-p", "rate_source:=gyro"], {}, "rate_source"),
    ("centroider_node", ["-p", "gyro.mounting_quaternion:=[0.0, 0.0, 0.0, 2.0]"], {}, "gyro.mounting_quaternion"),
    ("centroider_node", ["-p", "qos_overrides./imu.subscription.depth:=0"], {}, "depth 0"),
    ("centroider_node", ["-p", "qos_overrides./imu.subscription.reliability:=sometimes"], {}, "reliability"),
    ("centroider_node", ["--params-file", "/nonexistent/star_tracker.yaml"], {}, "no such file"),
    ("centroider_node", ["--params-file", "/tmp"], {}, "not a regular file"),
    ("identifier_node", [], {"STAR_TRACKER_CACHE": "A_FILE"}, "is not a directory"),
    ("camera_simulator_node", ["-p", "attitude.quaternion:=[.nan, 0.0, 0.0, 1.0]"], {}, "attitude.quaternion"),
])
def test_bad_startup_input_exits_with_one_clear_line(module, args, env_extra, message, tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a directory")
    env = {**isolated_ros_environment(), **{k: str(a_file) if v == "A_FILE" else v for k, v in env_extra.items()}}
    result = subprocess.run([sys.executable, "-m", f"star_tracker.ros.{module}", "--ros-args", *args],
                            env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stdout + result.stderr
    assert message in result.stderr and "Traceback" not in result.stderr, result.stderr
    assert "[star_tracker] fatal:" in result.stderr
