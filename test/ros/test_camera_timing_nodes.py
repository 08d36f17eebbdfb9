# SPDX-License-Identifier: Apache-2.0
"""
camera_simulator timing over DDS.

A frame rendered ahead is never published before its exposure, frame transfer and readout
have ended (wall clock and sim time), and it is still the frame its stamp says (pixel for
pixel the same as a render of that frame here); after a host stall only the backlog beyond
`max_backlog_frames` is skipped, counted.
"""
from __future__ import annotations

import os
import re
import signal
import time

import numpy as np
import pytest
pytestmark = pytest.mark.slow  # every test here starts processes (nodes or node executables)

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import QuaternionStamped  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.qos import qos_profile_sensor_data as SENSOR_QOS  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402

from star_tracker.models.attitude import quaternion_to_matrix  # noqa: E402
from star_tracker.models.camera import CameraModel  # noqa: E402
from star_tracker.models.catalog import julian_year_from_unix, load_hipparcos  # noqa: E402
from star_tracker.sim.motion import motion_from_parameters  # noqa: E402
from star_tracker.sim.render import FalseObjectModel, StarFieldRenderer, frame_seed  # noqa: E402
from star_tracker.sim.sensor import SensorModel  # noqa: E402
from star_tracker.ros import convert  # noqa: E402

from conftest import join_isolated_ros_domain  # noqa: E402
from star_tracker.ros.pipeline import NodeProcesses  # noqa: E402

# The truth the tests count against, deeper than the node's queue (qos.RESULT_QOS, depth 10): on
# a loaded host this process, decoding every image, fell behind a burst and its own reader
# queue dropped truth (13 of 27 in a CI rehearsal); the tests judge the camera, not this queue.
# The camera's best-effort images, kept in a history deep enough for every frame of a test: on a
# loaded host this process can fall behind the 10 Hz stream (the sensor-data depth of 5 lost 7 of 12).
IMAGE_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
TRUTH_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)

SIZE = 256  # small frames: cheap to render twice
QUATERNION = [0.1, -0.3, 0.2, 0.9273618495495704]  # unit (x, y, z, w)
EXPOSURE_S, ROW_TIME_S, TRANSFER_S, READOUT_S = 0.05, 2e-5, 1e-3, 0.03
# The camera's defaults that differ from SensorModel's, set explicitly on both sides.
SENSOR = {"vignetting_at_corner": 0.1, "dsnu_fraction": 0.1, "prnu_fraction": 0.01, "hot_pixel_fraction": 2e-5,
          "cosmic_ray_rate_per_cm2_s": 5.0}
PARAMS = {
    "image.width": SIZE, "image.height": SIZE, "attitude.profile": "fixed", "attitude.quaternion": QUATERNION,
    "sky.epoch_jyear": 2026.0, "seed": 7, "rate_hz": 10.0, "wait_for_subscribers": True,
    "max_backlog_frames": 100,  # a host stall makes frames late, never skipped (but in the test of skipping)
    "sensor.exposure_s": EXPOSURE_S, "sensor.rolling_shutter_row_time_s": ROW_TIME_S,
    "sensor.frame_transfer_time_s": TRANSFER_S, "sensor.readout_s": READOUT_S,
    "optics.vignetting_at_corner": SENSOR["vignetting_at_corner"],
    **{f"sensor.{k}": v for k, v in SENSOR.items() if k != "vignetting_at_corner"},
}
# Middle row's exposure end -> frame deliverable: the last row, the transfer, the readout.
DELIVERY_AFTER_STAMP_NS = round((EXPOSURE_S / 2 + ROW_TIME_S * (SIZE - 1) / 2 + TRANSFER_S + READOUT_S) * 1e9)


@pytest.fixture
def driver(monkeypatch):
    env = join_isolated_ros_domain(monkeypatch)
    node = rclpy.create_node("camera_timing_driver")
    yield env, node
    node.destroy_node()
    rclpy.try_shutdown()


def subscribe(node, received_at):
    """image_raw -> (stamp, receive time from received_at(), image); truth stamps."""
    images, truth = [], []
    node.create_subscription(Image, "image_raw", lambda m: images.append(
        (convert.stamp_to_ns(m.header.stamp), received_at(), convert.image_to_array(m))), IMAGE_QOS)
    node.create_subscription(QuaternionStamped, "truth/attitude", truth.append, TRUTH_QOS)
    node.create_subscription(CameraInfo, "camera_info", lambda _msg: None, SENSOR_QOS)  # wait_for_subscribers
    return images, truth


def renderer_like_the_node() -> StarFieldRenderer:
    camera = CameraModel.from_fov(SIZE, SIZE, np.radians(15.0))
    sensor = SensorModel(exposure_s=EXPOSURE_S, rolling_shutter_row_time_s=ROW_TIME_S,
                         frame_transfer_time_s=TRANSFER_S, **SENSOR)
    return StarFieldRenderer(camera, sensor, load_hipparcos().at_epoch(2026.0), 7.5, FalseObjectModel())


def assert_frames_are_the_rendered_ones(images, truth, period_ns: int) -> None:
    """
    Each image equals this process's render of its frame.

    Frame k is the k-th truth stamp (truth is reliable and the camera waited for its
    subscriber, so frame 0's truth arrives).
    """
    renderer = renderer_like_the_node()
    motion = motion_from_parameters("fixed", quaternion_to_matrix(np.asarray(QUATERNION)))
    frame0 = convert.stamp_to_ns(truth[0].header.stamp)
    for stamp, _, image in images:
        k = (stamp - frame0) // period_ns
        assert stamp == frame0 + k * period_ns, "stamps on the frame grid"
        assert np.array_equal(renderer.render(motion, stamp * 1e-9, frame_seed(7, k)).image, image), k


def run_wall_clock_camera(env, node, tmp_path, params: dict, truth: list) -> str:
    """Run a camera_simulator with `params` (max_frames set) until its truth is in, and 1 s more; return its log."""
    cam = NodeProcesses(env, tmp_path / "logs", {"camera_simulator": params}, nodes=("camera_simulator",)).start()
    try:
        cam.wait_ready()
        end = time.monotonic() + 30.0  # ~1 s of frames at 10 Hz; generous for a loaded host
        while time.monotonic() < end and len(truth) < params["max_frames"]:
            rclpy.spin_once(node, timeout_sec=0.02)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.02)
    finally:
        codes = cam.stop()
    log = (tmp_path / "logs" / "camera_simulator.log").read_text()
    assert codes == {"camera_simulator": 0}, log
    return log


@pytest.mark.integration
def test_frames_are_published_after_exposure_and_readout_wall_clock(driver, tmp_path):
    env, node = driver
    images, truth = subscribe(node, time.time_ns)  # the nodes' clock: this host's wall clock
    frames = 12
    log = run_wall_clock_camera(env, node, tmp_path, {**PARAMS, "max_frames": frames}, truth)
    assert len(truth) == frames and len(images) >= frames - 2, log  # best-effort images may lose a couple
    early = [(stamp, received) for stamp, received, _ in images if received < stamp + DELIVERY_AFTER_STAMP_NS]
    assert not early, f"published before exposure + transfer + readout ended: {early}"
    assert_frames_are_the_rendered_ones(images, truth, 100_000_000)


@pytest.mark.integration
def test_frames_wait_for_sim_time(driver, tmp_path):
    """
    use_sim_time with a clock at half speed.

    A frame rendered ahead waits for /clock to pass its delivery time (a wall-clock wait
    would publish it early).
    """
    env, node = driver
    clock = {"ns": 1_000_000_000_000}  # the newest /clock this test has published
    images, truth = subscribe(node, lambda: clock["ns"])
    pub_clock = node.create_publisher(Clock, "/clock", 10)
    frames = 8
    cam = NodeProcesses(env, tmp_path / "logs", {"camera_simulator": {**PARAMS, "max_frames": frames,
                                                                      "use_sim_time": True}},
                        nodes=("camera_simulator",)).start()
    try:
        cam.wait_ready()
        end = time.monotonic() + 40.0  # 8 frames at 10 Hz of half-speed time take ~2 s
        while time.monotonic() < end and len(truth) < frames:
            clock["ns"] += 2_500_000  # 2.5 ms of sim time per ~5 ms of wall time
            pub_clock.publish(Clock(clock=convert.ns_to_stamp(clock["ns"])))
            rclpy.spin_once(node, timeout_sec=0.005)
        for _ in range(100):  # the last images (the clock keeps going)
            clock["ns"] += 2_500_000
            pub_clock.publish(Clock(clock=convert.ns_to_stamp(clock["ns"])))
            rclpy.spin_once(node, timeout_sec=0.005)
    finally:
        codes = cam.stop()
    log = (tmp_path / "logs" / "camera_simulator.log").read_text()
    assert codes == {"camera_simulator": 0}, log
    assert len(truth) == frames and len(images) >= frames - 2, log
    stamps = [stamp for stamp, _, _ in images]
    assert min(stamps) > 1_000_000_000_000, "stamps on sim time"
    early = [(stamp, seen) for stamp, seen, _ in images if seen < stamp + DELIVERY_AFTER_STAMP_NS]
    assert not early, f"published before its delivery time on /clock: {early}"
    assert_frames_are_the_rendered_ones(images, truth, 100_000_000)


@pytest.mark.integration
def test_a_stalled_camera_skips_only_the_backlog_beyond_its_limit(driver, tmp_path):
    """
    A host stall of 1.5 s at 10 Hz leaves ~15 frames due at once.

    The camera publishes the newest `max_backlog_frames` of them late and skips the older
    ones, counted and logged; every published frame keeps its own stamp on the frame grid.
    """
    env, node = driver
    images, truth = subscribe(node, time.time_ns)
    diagnostics = {}
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: diagnostics.update(
        {kv.key: kv.value for status in msg.status if status.name.endswith("camera_simulator")
         for kv in status.values}), 10)
    # Enough frames that the stall ends well before the last one even when a loaded host
    # delivers the first five late (with 40, the schedule's end clamped the frames due).
    frames, backlog = 100, 2
    cam = NodeProcesses(env, tmp_path / "logs", {"camera_simulator": {**PARAMS, "max_frames": frames,
                                                                      "max_backlog_frames": backlog}},
                        nodes=("camera_simulator",)).start()
    try:
        cam.wait_ready()
        end = time.monotonic() + 30.0
        while time.monotonic() < end and len(truth) < 5:
            rclpy.spin_once(node, timeout_sec=0.02)
        pid = cam.processes["camera_simulator"].pid
        os.kill(pid, signal.SIGSTOP)  # the host stall
        time.sleep(1.5)
        os.kill(pid, signal.SIGCONT)

        def done() -> bool:
            counted = (int(diagnostics.get("frames_published", "0"))
                       + int(diagnostics.get("frames_skipped_overrun", "0")))
            return counted >= frames and len(truth) >= int(diagnostics.get("frames_published", "0"))
        end = time.monotonic() + 30.0
        while time.monotonic() < end and not done():
            rclpy.spin_once(node, timeout_sec=0.02)
    finally:
        codes = cam.stop()
    log = (tmp_path / "logs" / "camera_simulator.log").read_text()
    assert codes == {"camera_simulator": 0}, log
    skipped = int(diagnostics.get("frames_skipped_overrun", "0"))
    # 15 frames fell due in the stall: all but `backlog` of them are skipped (the default
    # backlog, 5, would skip at most 11).
    assert skipped >= 15 - backlog - 1, (diagnostics, log)
    assert len(truth) + skipped == frames and int(diagnostics["frames_published"]) == len(truth), diagnostics
    assert sum(int(n) for n in re.findall(r"skipped (\d+) frame\(s\)", log)) == skipped, log  # each skip logged
    period_ns = 100_000_000
    stamps = np.array([convert.stamp_to_ns(m.header.stamp) for m in truth])
    gaps = np.diff(stamps) // period_ns
    assert np.all(np.diff(stamps) % period_ns == 0) and np.all(gaps >= 1), "stamps on the frame grid, increasing"
    assert int(np.sum(gaps - 1)) == skipped, gaps  # the skipped frames are missing from the grid, nothing else
    assert_frames_are_the_rendered_ones(images, truth, period_ns)


@pytest.mark.integration
def test_on_sim_time_the_stars_are_at_the_sim_clocks_date(driver, tmp_path):
    """
    sky.epoch_jyear 0 (the clock's date) on a sim clock that starts after the node configured, in 2037.

    Each image equals a render of the catalog propagated to its stamp's date, not to the wall
    clock's or to 1970's (the node's clock before the first /clock).
    """
    env, node = driver
    start_ns = 2_127_600_000 * 1_000_000_000  # 2037-06-01 00:00 UTC (ROS time's int32 seconds end in 2038)
    clock = {"ns": start_ns}
    images, truth = subscribe(node, lambda: clock["ns"])
    pub_clock = node.create_publisher(Clock, "/clock", 10)
    frames = 4
    params = {**PARAMS, "sky.epoch_jyear": 0.0, "max_frames": frames, "use_sim_time": True}
    cam = NodeProcesses(env, tmp_path / "logs", {"camera_simulator": params}, nodes=("camera_simulator",)).start()
    try:
        cam.wait_ready()  # configured before any /clock: the node's clock still reads 0
        end = time.monotonic() + 40.0
        while time.monotonic() < end and (len(truth) < frames or len(images) < frames - 1):
            clock["ns"] += 5_000_000
            pub_clock.publish(Clock(clock=convert.ns_to_stamp(clock["ns"])))
            rclpy.spin_once(node, timeout_sec=0.005)
    finally:
        codes = cam.stop()
    log = (tmp_path / "logs" / "camera_simulator.log").read_text()
    assert codes == {"camera_simulator": 0}, log
    assert images, log
    motion = motion_from_parameters("fixed", quaternion_to_matrix(np.asarray(QUATERNION)))
    frame0 = convert.stamp_to_ns(truth[0].header.stamp)
    catalog = load_hipparcos()
    for stamp, _, image in images:
        k = (stamp - frame0) // 100_000_000
        renders = {}
        for epoch in (julian_year_from_unix(stamp * 1e-9), 2026.0):
            renderer = StarFieldRenderer(CameraModel.from_fov(SIZE, SIZE, np.radians(15.0)),
                                         SensorModel(exposure_s=EXPOSURE_S, rolling_shutter_row_time_s=ROW_TIME_S,
                                                     frame_transfer_time_s=TRANSFER_S, **SENSOR),
                                         catalog.at_epoch(epoch), 7.5, FalseObjectModel())
            renders[epoch] = renderer.render(motion, stamp * 1e-9, frame_seed(7, k)).image
        at_stamp, today = renders.values()
        assert np.array_equal(at_stamp, image), k
        assert not np.array_equal(today, image), k  # the test can tell the epochs apart


@pytest.mark.integration
def test_synchronised_exposures_are_stamped_on_the_clocks_period_grid(driver, tmp_path):
    """sync_exposures: every stamp (mid-exposure) is a multiple of the period (wall clock), never published early."""
    env, node = driver
    images, truth = subscribe(node, time.time_ns)
    frames = 8
    params = {**PARAMS, "max_frames": frames, "sync_exposures": True, "start_delay_s": 0.0123}
    log = run_wall_clock_camera(env, node, tmp_path, params, truth)
    assert len(truth) == frames and len(images) >= frames - 2, log
    period_ns = 100_000_000
    stamps = [convert.stamp_to_ns(m.header.stamp) for m in truth]
    assert all(stamp % period_ns == 0 for stamp in stamps), stamps
    early = [(stamp, received) for stamp, received, _ in images if received < stamp + DELIVERY_AFTER_STAMP_NS]
    assert not early, f"published before exposure + transfer + readout ended: {early}"
    assert_frames_are_the_rendered_ones(images, truth, period_ns)
