# SPDX-License-Identifier: Apache-2.0
"""
Overload and faults through the real nodes (separate processes, Fast DDS, isolated domain).

- Input faster than processing: a burst of frames, as deep as the DDS queues, is published
  back to back into the centroider, then the identifier (the overload does not depend on this
  test outrunning the node frame by frame on a loaded host); the frames they had no time for
  are counted (`frames_dropped_overload`, newest frame wins), every received frame is
  accounted for, and the newest frame is the one answered, with the true attitude.
- Kill -9 the identifier mid-run and restart it: every frame the new process receives is
  identified, from the first one (re-acquisition within one frame), against simulator truth.
- Restart the camera: the centroider and identifier carry on with the new frames.
- SIGINT and SIGTERM each stop every node with exit code 0 (no timing assertion beyond the
  generous deadline of NodeProcesses.stop, after which it would SIGKILL: exit code -9).
"""
from __future__ import annotations

import signal
import time

import numpy as np
import pytest
pytestmark = pytest.mark.slow  # every test here starts processes (nodes or node executables)

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import QuaternionStamped  # noqa: E402
from rclpy.qos import qos_profile_sensor_data as SENSOR_QOS  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2  # noqa: E402

from star_tracker.models.attitude import attitude_error, quaternion_to_matrix, radec_roll_to_matrix  # noqa: E402
from star_tracker.models.camera import CameraModel  # noqa: E402
from star_tracker.sim.motion import ConstantRateMotion  # noqa: E402
from star_tracker.sim.render import StarFieldRenderer, frame_seed  # noqa: E402
from star_tracker.sim.sensor import SensorModel  # noqa: E402
from star_tracker.ros import convert  # noqa: E402
from star_tracker.ros.qos import IMAGE_QOS, RESULT_QOS, SPOTS_QOS  # noqa: E402
from star_tracker.ros.pipeline import NodeProcesses, TrackerMonitor  # noqa: E402
from test_bad_input_nodes import Driver  # noqa: E402  the diagnostics-reading test node
from conftest import spots_at  # noqa: E402
from test_integration import REPO, ros_graph  # noqa: E402,F401  the isolated-domain fixture

ARCSEC = np.radians(1 / 3600)
FRAME = convert.OPTICAL_FRAME
MS = 1_000_000


def stamped(msg, stamp_ns: int):
    msg.header.stamp = convert.ns_to_stamp(stamp_ns)
    msg.header.frame_id = FRAME
    return msg


def accounted(counters: dict[str, str], outcomes: tuple[str, ...]) -> int:
    """Frames a node received that ended in one of `outcomes` (counter names or prefixes)."""
    return sum(int(v) for k, v in counters.items() if k.startswith(outcomes))


def burst(messages: list) -> float:
    """
    Publish (publisher, serialized message) pairs back to back.

    Serialized beforehand and never yielding the CPU in between (a sleep would hand it to the
    node on a loaded host), the burst takes a few memory copies, not the node's pace. Returns
    its duration [s].
    """
    started = time.perf_counter()
    for publisher, data in messages:
        publisher.publish(data)
    return time.perf_counter() - started


class FloodRig:
    """
    This test's side of the flood.

    Publishers into the centroider and the identifier, the outputs seen (spots and attitude
    stamps), and the two nodes' diagnostics.
    """

    def __init__(self):
        self.centroider, self.identifier = Driver("centroider"), Driver("identifier")
        node = self.node = self.centroider.node
        self.spots_seen: set[int] = set()
        self.attitudes: dict[int, np.ndarray] = {}
        self.last_output = time.monotonic()
        node.create_subscription(PointCloud2, "spots", self._on_spots, SENSOR_QOS)
        node.create_subscription(QuaternionStamped, "attitude", self._on_attitude, RESULT_QOS)
        # The nodes' own QoS (queue depths 10 and 20): a burst is not cut short on this side.
        self.pub_image = node.create_publisher(Image, "image_raw", IMAGE_QOS)
        self.pub_info = node.create_publisher(CameraInfo, "camera_info", IMAGE_QOS)
        self.pub_spots = node.create_publisher(PointCloud2, "spots", SPOTS_QOS)

    def _on_spots(self, msg) -> None:
        self.spots_seen.add(convert.stamp_to_ns(msg.header.stamp))
        self.last_output = time.monotonic()

    def _on_attitude(self, msg) -> None:
        self.attitudes[convert.stamp_to_ns(msg.header.stamp)] = quaternion_to_matrix(convert.quaternion_from_msg(msg))
        self.last_output = time.monotonic()

    def spin(self, seconds: float, until=lambda: False) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            rclpy.spin_once(self.node, timeout_sec=0.02)
            rclpy.spin_once(self.identifier.node, timeout_sec=0)
        return until()

    def publish_image(self, image, info, stamp_ns: int) -> None:
        self.pub_info.publish(stamped(info, stamp_ns))
        self.pub_image.publish(stamped(image, stamp_ns))

    def destroy(self) -> None:
        self.node.destroy_node()
        self.identifier.node.destroy_node()


def counted_since(baseline: dict[str, str], counters: dict[str, str], outcomes: tuple[str, ...]) -> int:
    """How many more frames ended in `outcomes` (counter names or prefixes) than at `baseline`."""
    return accounted(counters, outcomes) - accounted(baseline, outcomes)


@pytest.mark.integration
def test_flooded_nodes_count_dropped_frames_and_answer_the_newest(ros_graph,  # noqa: F811  the fixture
                                                                  tmp_path, catalog):
    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0))
    truth = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.3)
    renderer = StarFieldRenderer(camera, SensorModel(exposure_s=0.02), catalog.at_epoch(2026.0), 7.5)
    images = [convert.array_to_image(renderer.render(ConstantRateMotion(truth, np.zeros(3)), 1.0,
                                                     frame_seed(0, k)).image,
                                     0, FRAME) for k in range(4)]
    star_spots = convert.spots_to_cloud(spots_at(catalog.brighter_than(6.8).at_epoch(2026.0), camera, truth), 0, FRAME)
    info = convert.camera_to_info(camera, 0, FRAME)
    rig = FloodRig()
    nodes = NodeProcesses(ros_graph, tmp_path / "logs", {"centroider": {"exposure_time_s": 0.02}},
                          REPO / "config" / "star_tracker.yaml", nodes=("centroider", "identifier"))
    try:
        nodes.start()
        nodes.wait_ready()
        assert rig.spin(20.0,
                        lambda: all(p.get_subscription_count() > 0
                                    for p in (rig.pub_image, rig.pub_info, rig.pub_spots)))
        base = time.time_ns() - 30 * 10**9
        # One frame answered end to end first (best effort may lose the first messages after matching).
        for attempt in range(20):
            rig.publish_image(images[0], info, base + attempt * MS)
            if rig.spin(2.0, lambda: any(s >= base for s in rig.attitudes)):
                break
        # Late answers to copies of that frame (a loaded host) must not count below: wait until
        # the nodes have been quiet for 3 s (the 1 Hz diagnostics have caught up), then count.
        rig.spin(60.0, lambda: time.monotonic() - rig.last_output > 3.0)
        baseline_c, baseline_i = dict(rig.centroider.counters), dict(rig.identifier.counters)
        # A loaded host's shared-memory transport can lose most of a best-effort burst before the
        # centroider receives it (CI rehearsal of 6878c03: 1 of 10 received): then nothing was there
        # to drop, so the burst is sent again (at most 3 times), each judged from its own baseline.
        for attempt in range(3):
            centroider_counters, stamps = flood_centroider(rig, images, info, base + (1 + attempt) * 10**9,
                                                           baseline_c)
            received = int(centroider_counters.get("frames_received", 0)) - int(baseline_c.get("frames_received", 0))
            if received > 5:  # more than the 3 waiting places and the frame in progress
                break
            baseline_c = {k: v for k, v in centroider_counters.items() if k != "burst_s"}
        # A burst the publisher could only send slowly (a loaded host) may reach the identifier no
        # faster than it tracks: nothing to drop. Sent again (at most 3 times), each judged from its
        # own baseline.
        for attempt in range(3):
            identifier_counters, spot_stamps = flood_identifier(rig, star_spots, stamps[-1] + (1 + attempt) * 10**9,
                                                                baseline_i, base)
            dropped = int(identifier_counters.get("frames_dropped_overload", 0)) \
                - int(baseline_i.get("frames_dropped_overload", 0))
            if dropped > 0:
                break
            baseline_i = {k: v for k, v in identifier_counters.items() if k != "burst_s"}
    finally:
        codes = nodes.stop(sig=signal.SIGINT)
        rig.destroy()
    logs = {name: path.read_text() for name, path in nodes.log_paths.items()}
    assert codes == {"centroider": 0, "identifier": 0}, logs
    assert not any("Traceback" in text for text in logs.values()), logs

    delta_c = lambda key: int(centroider_counters.get(key, 0)) - int(baseline_c.get(key, 0))  # noqa: E731
    # Frames the centroider had no time for were counted, not lost without a trace...
    assert delta_c("frames_dropped_overload") > 0, centroider_counters
    assert delta_c("frames_processed") + delta_c("frames_dropped_overload") == delta_c("frames_received")
    assert delta_c("frames_processed") < len(stamps)
    # ... and the newest frame was measured and identified, with the true attitude.
    newest = stamps[-1]
    assert newest in rig.spots_seen
    assert attitude_error(rig.attitudes[newest], truth)[2] < 10 * ARCSEC
    assert "newest frame wins" in logs["centroider"]

    delta_i = lambda key: int(identifier_counters.get(key, 0)) - int(baseline_i.get(key, 0))  # noqa: E731
    assert delta_i("frames_dropped_overload") > 0, identifier_counters
    assert not any(k.startswith("not_identified_") and delta_i(k) for k in identifier_counters), identifier_counters
    assert attitude_error(rig.attitudes[spot_stamps[-1]], truth)[2] < 10 * ARCSEC
    answered = [s for s in spot_stamps if s in rig.attitudes]
    assert len(answered) <= delta_i("frames_identified")
    assert all(attitude_error(rig.attitudes[s], truth)[2] < 10 * ARCSEC for s in answered)
    assert "newest frame wins" in logs["identifier"]


def flood_centroider(rig: FloodRig, images, info, first_ns: int, baseline: dict):
    """
    Publish a burst of 10 images, 10 ms apart in stamps.

    10 is the depth of the DDS queues on both sides: none is lost there. They are
    published faster than the centroider measures one 1024^2 frame: more than its 3 waiting
    places and the frame in progress. Returns its counters once every received frame is
    accounted (processed or dropped), and the stamps sent.
    """
    stamps = [first_ns + k * 10 * MS for k in range(10)]
    burst_s = burst([(publisher, serialize_message(stamped(msg, stamp)))
                     for k, stamp in enumerate(stamps)
                     for publisher, msg in ((rig.pub_info, info), (rig.pub_image, images[k % len(images)]))])
    newest = stamps[-1]
    counters = rig.centroider
    assert rig.spin(30.0, lambda: newest in rig.attitudes), (burst_s, counters.counters, sorted(rig.spots_seen)[-3:])

    def settled():
        received = int(counters.counters.get("frames_received", 0)) - int(baseline.get("frames_received", 0))
        return counted_since(baseline, counters.counters,
                             ("frames_processed", "frames_dropped_overload")) == received > 0
    assert rig.spin(10.0, settled), (counters.counters, baseline)
    return {**counters.counters, "burst_s": f"{burst_s:.3f}"}, stamps


def flood_identifier(rig: FloodRig, star_spots, first_ns: int, baseline: dict, base: int):
    """
    Publish a burst of 20 spots messages, at rest, 1 ms apart in stamps.

    20 is the depth of the DDS queues on both sides. They are published faster than the
    identifier tracks one frame. Returns its counters once every received frame is accounted
    (identified, dropped or not identified), and the stamps sent.
    """
    spot_stamps = [first_ns + k * MS for k in range(20)]
    burst_s = burst([(rig.pub_spots, serialize_message(stamped(star_spots, stamp))) for stamp in spot_stamps])
    newest = spot_stamps[-1]
    counters = rig.identifier
    assert rig.spin(30.0, lambda: newest in rig.attitudes), (burst_s, counters.counters)
    received = lambda: (int(counters.counters.get("frames_received", 0))  # noqa: E731
                        - int(baseline.get("frames_received", 0)))
    outcomes = ("frames_identified", "frames_dropped_overload", "not_identified_")
    # Fresh counters: the identifier received at least every frame it answered since the baseline.
    answered_since = lambda: sum(s > base for s in rig.attitudes)  # noqa: E731
    assert rig.spin(10.0, lambda: received() >= answered_since()
                    and counted_since(baseline, counters.counters, outcomes) == received()), \
        (counters.counters, baseline)
    return {**counters.counters, "burst_s": f"{burst_s:.3f}"}, spot_stamps


@pytest.mark.integration
def test_identifier_killed_and_camera_restarted_mid_run(ros_graph, tmp_path):  # noqa: F811  the fixture
    monitor = TrackerMonitor(name="overload_monitor")
    params = {"camera_simulator": {"rate_hz": 5.0, "sensor.exposure_s": 0.02, "wait_for_subscribers": True,
                                   "attitude.body_rate_deg_s": [0.3, 0.4, 0.05]},
              "centroider": {"exposure_time_s": 0.02}}
    nodes = NodeProcesses(ros_graph, tmp_path / "logs", params, REPO / "config" / "star_tracker.yaml")

    def identified_after(stamp_ns: int) -> list:
        return [f for ns, f in sorted(monitor.frames.items()) if ns > stamp_ns and f.attitude is not None]

    try:
        nodes.start()
        nodes.wait_ready()
        assert monitor.spin_for(60.0, until=lambda: len(identified_after(0)) >= 5)
        first_identifier = nodes.processes["identifier"].pid

        # kill -9 mid-run, then a new identifier process: it has no track and must re-acquire.
        assert nodes.kill("identifier", signal.SIGKILL) == -signal.SIGKILL
        killed_ns = time.time_ns()
        nodes.restart("identifier")
        monitor.spin_for(0.5)  # the dead process's last diagnostics, still queued: then forget them
        monitor.diagnostics.pop("star_tracker/identifier", None)
        assert monitor.spin_for(60.0, until=lambda: len(identified_after(killed_ns)) >= 5)
        # The new process's counters: every frame it received was identified, from its first
        # (a frame that came during a long first solve on a loaded host is bridged, and the
        # newest bridged one published, docs/RELIABILITY.md: identified with the solve; spots
        # that beat the first camera_info to the new process cannot be identified by anyone).
        # Judged once its counters show it past its camera_info, however late that came (a
        # loaded host once delivered 9 spots first): they then show identified frames. The
        # attitudes above may outrun the 1 Hz diagnostics, so they do not tell.
        restarted = lambda: monitor.diagnostics.get("star_tracker/identifier", {})  # noqa: E731
        outcomes = ("frames_identified", "frames_bridged", "frames_dropped_overload", "frames_without_camera_info")
        assert monitor.spin_for(10.0, until=lambda: int(restarted().get("frames_identified", 0)) >= 3
                                and accounted(restarted(), outcomes) == int(restarted()["frames_received"])), \
            restarted()
        after_kill = dict(restarted())

        # The camera restarted (SIGTERM: exits cleanly): the centroider and identifier carry on.
        assert nodes.kill("camera_simulator", signal.SIGTERM) == 0
        camera_restarted_ns = time.time_ns()
        nodes.restart("camera_simulator")
        assert monitor.spin_for(60.0, until=lambda: len(identified_after(camera_restarted_ns)) >= 10)
        # Judged: the frames whose spots were out by now, given 2 s for their attitude (CI once
        # stopped the nodes with the newest frames' identification still in flight).
        judged_until = max(ns for ns, f in monitor.frames.items() if f.spot_count)
        monitor.spin_for(2.0)
        assert monitor.spin_for(5.0, until=lambda: all(f.truth is not None for f in identified_after(killed_ns)))
        running = {name: proc.poll() for name, proc in nodes.processes.items()}
        identifier_pid = nodes.processes["identifier"].pid
    finally:
        codes = nodes.stop(sig=signal.SIGTERM)  # mid-run: the camera is still publishing
        frames = [monitor.frames[ns] for ns in sorted(monitor.frames)]
        monitor.destroy_node()
    logs = {path.name: path.read_text() for path in (tmp_path / "logs").glob("*.log")}
    assert codes == {"camera_simulator": 0, "centroider": 0, "identifier": 0}, logs
    assert running == {"camera_simulator": None, "centroider": None, "identifier": None}, logs
    assert identifier_pid != first_identifier
    assert not any("Traceback" in text for text in logs.values()), logs

    assert not any(k.startswith(("not_identified_", "frames_failed", "frames_not_bridged", "bridge_not_verified"))
                   for k in after_kill), after_kill
    assert "last_identify_ms" in after_kill  # it did start from nothing: a lost-in-space solve
    # Every attitude, before the kill, after the restart and from the restarted camera, is true.
    solved = [f for f in frames if f.attitude is not None and f.truth is not None]
    assert len(solved) >= 15
    errors = np.array([f.error()[2] for f in solved])
    assert np.all(errors < 60 * ARCSEC), np.degrees(errors.max()) * 3600
    # After each restart, the frames go on being identified (a frame bridged during a long
    # lost-in-space solve is not published by itself, docs/RELIABILITY.md: hence not all).
    for since in (killed_ns, camera_restarted_ns):
        resumed = next(f.stamp_ns for f in frames if f.stamp_ns > since and f.attitude is not None)
        later = [f for f in frames if resumed <= f.stamp_ns <= judged_until and f.spot_count]
        assert sum(f.attitude is not None for f in later) >= 0.8 * len(later), (
            [(f.stamp_ns, f.attitude is not None) for f in later], logs["identifier.restart1.log"])
