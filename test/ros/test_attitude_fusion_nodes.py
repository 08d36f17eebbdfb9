# SPDX-License-Identifier: Apache-2.0
"""
The attitude_fusion node with two real heads, every node its own process over Fast DDS (no ROS mocks).

Two heads 90 deg apart on one body at rest: head1 along body +Z, head2 along body +X (the
node's default mountings). Each head is a camera_simulator + centroider + identifier in its
namespace; its camera renders the body attitude through its mounting (`attitude.quaternion` =
body attitude composed with the mounting: the simulator does not know mountings yet). Judged
against the simulator's truth and the nodes' own counts, never host timing.
"""
from __future__ import annotations

import signal
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.integration, pytest.mark.slow]  # starts seven node processes

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped  # noqa: E402
from rclpy.node import Node  # noqa: E402

from conftest import join_isolated_ros_domain  # noqa: E402
from star_tracker.identify import DEFAULT_ALGORITHM, IdentifyConfig, make_identifier  # noqa: E402
from star_tracker.models.attitude import (ARCSEC, matrix_to_quaternion, matrix_to_rotation_vector,  # noqa: E402
                                          quaternion_to_matrix, radec_roll_to_matrix)
from star_tracker.ros import convert  # noqa: E402
from star_tracker.ros.attitude_fusion_parameters import DEFAULT_MOUNTINGS  # noqa: E402
from star_tracker.ros.pipeline import MONITOR_RESULT_QOS, NodeProcesses  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
HEADS = ("head1", "head2")
RATE_HZ = 5.0  # each camera; 200 ms a frame leaves this 2-core host room for seven processes
BOTH_FUSED = 30  # fused attitudes with both heads judged for accuracy
ALONE_FUSED = 5  # fused attitudes from head1 alone once head2 is stale
BODY = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), np.radians(30.0))  # body -> ICRS, the truth
START_TIMEOUT_S = 300.0  # seven processes starting on two cores (the kernels are cached)
PHASE_TIMEOUT_S = 120.0


def head_attitude(head: str) -> np.ndarray:
    """Return the head's sensor -> ICRS attitude: the body attitude composed with its mounting."""
    return BODY @ quaternion_to_matrix(np.array(DEFAULT_MOUNTINGS[head]))


def error_body(rotation: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Return the small-angle error [rad] of an attitude about its own (child) frame's axes: log(truth^T R)."""
    return matrix_to_rotation_vector(truth.T @ rotation)


class FusionMonitor(Node):
    """Every head's truth and solution, the fused attitudes, fusion_status, alignment and /diagnostics."""

    def __init__(self):
        super().__init__("fusion_monitor")
        self.truth: dict[str, dict[int, np.ndarray]] = {h: {} for h in HEADS}
        self.solutions: dict[str, dict[int, np.ndarray]] = {h: {} for h in HEADS}
        self.fused: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # stamp -> (rotation, covariance)
        self.fused_quaternions: dict[int, np.ndarray] = {}
        self.status: list[tuple[int, dict[str, dict]]] = []  # (stamp, status name -> {level, message, values})
        self.alignment: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.diagnostics: dict[str, dict[str, str]] = {}
        for head in HEADS:
            self.create_subscription(QuaternionStamped, f"{head}/truth/attitude",
                                     lambda m, h=head: self._keep(self.truth[h], m), MONITOR_RESULT_QOS)
            self.create_subscription(QuaternionStamped, f"{head}/attitude",
                                     lambda m, h=head: self._keep(self.solutions[h], m), MONITOR_RESULT_QOS)
        self.create_subscription(QuaternionStamped, "attitude", lambda m: self._keep(self.fused_quaternions, m),
                                 MONITOR_RESULT_QOS)
        self.create_subscription(PoseWithCovarianceStamped, "attitude_with_covariance", self._on_fused,
                                 MONITOR_RESULT_QOS)
        self.create_subscription(DiagnosticArray, "fusion_status", self._on_status, MONITOR_RESULT_QOS)
        self.create_subscription(PoseWithCovarianceStamped, "alignment/head2", self._on_alignment, MONITOR_RESULT_QOS)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)

    @staticmethod
    def _keep(store: dict, msg: QuaternionStamped) -> None:
        store[convert.stamp_to_ns(msg.header.stamp)] = quaternion_to_matrix(convert.quaternion_from_msg(msg))

    def _on_fused(self, msg: PoseWithCovarianceStamped) -> None:
        o = msg.pose.pose.orientation
        self.fused[convert.stamp_to_ns(msg.header.stamp)] = (
            quaternion_to_matrix(np.array([o.x, o.y, o.z, o.w])), np.asarray(msg.pose.covariance).reshape(6, 6)[3:, 3:])

    def _on_status(self, msg: DiagnosticArray) -> None:
        self.status.append((convert.stamp_to_ns(msg.header.stamp), {
            s.name: {"level": s.level, "message": s.message, **{kv.key: kv.value for kv in s.values}}
            for s in msg.status}))

    def _on_alignment(self, msg: PoseWithCovarianceStamped) -> None:
        o = msg.pose.pose.orientation
        self.alignment.append((convert.stamp_to_ns(msg.header.stamp),
                               matrix_to_rotation_vector(quaternion_to_matrix(np.array([o.x, o.y, o.z, o.w]))),
                               np.asarray(msg.pose.covariance).reshape(6, 6)[3:, 3:]))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}

    def fusion_counter(self, key: str) -> int:
        return int(self.diagnostics.get("star_tracker/attitude_fusion", {}).get(key, "0"))

    def spin_until(self, until, timeout_s: float, what: str, check_alive=lambda: None) -> None:
        end = time.monotonic() + timeout_s
        while not until():
            if time.monotonic() > end:
                raise AssertionError(f"{what}: not within {timeout_s} s; fusion diagnostics: "
                                     f"{self.diagnostics.get('star_tracker/attitude_fusion')}")
            rclpy.spin_once(self, timeout_sec=0.05)
            check_alive()

    def statuses_since(self, index: int, heads_used: str) -> list[tuple[int, dict]]:
        return [(stamp, s) for stamp, s in self.status[index:] if s["fused"].get("heads_used") == heads_used]


@pytest.fixture
def ros_graph(monkeypatch):
    env = join_isolated_ros_domain(monkeypatch)
    yield env
    rclpy.try_shutdown()


@pytest.fixture
def built_caches(database):
    """Build the pattern database and the deep catalog once here, not in two identifiers at once."""
    make_identifier(DEFAULT_ALGORITHM, database, IdentifyConfig())


def head_processes(env, log_dir: Path, head: str, index: int) -> tuple[NodeProcesses, NodeProcesses]:
    """Return the head's processing nodes and its camera, in namespace /<head>."""
    remaps = {name: {"__ns": f"/{head}"} for name in ("camera_simulator", "centroider", "identifier")}
    camera = {"rate_hz": RATE_HZ, "wait_for_subscribers": True, "start_delay_s": 1.0, "frame_id": f"{head}_optical",
              "attitude.quaternion": [float(v) for v in matrix_to_quaternion(head_attitude(head))],
              "seed": 10 + index, "fixed_pattern_seed": 20 + index}
    yaml = REPO / "config" / "star_tracker.yaml"
    return (NodeProcesses(env, log_dir / head, {}, yaml, nodes=("centroider", "identifier"), remaps=remaps),
            NodeProcesses(env, log_dir / head, {"camera_simulator": camera}, yaml, nodes=("camera_simulator",),
                          remaps=remaps))


def test_two_heads_fuse_to_the_truth_and_survive_a_lost_head(ros_graph, tmp_path, monkeypatch, built_caches):
    # The simulated mountings are exact: the alignment filter starts from a 1" prior (a good
    # ground alignment) and must stay consistent with zero. The body is at rest, and the fusion
    # is told so: the identifiers' rates are stated to 0.23 deg/s at 5 Hz (their acceleration
    # allowance), which would leave the heads, exposed up to 100 ms apart, little to share.
    fusion_params = {"alignment.initial_sigma_rad": ARCSEC, "body_rate.source": "none"}
    fusion = NodeProcesses(ros_graph, tmp_path / "logs", {"attitude_fusion": fusion_params},
                           REPO / "config" / "star_tracker.yaml", nodes=("attitude_fusion",))
    heads = {head: head_processes(ros_graph, tmp_path / "logs", head, i) for i, head in enumerate(HEADS)}
    monitor = FusionMonitor()

    def check_alive() -> None:
        for processors, camera in heads.values():
            for nodes in (processors, camera):
                for name, proc in nodes.processes.items():
                    if proc.poll() is not None and not (nodes is heads["head2"][0] and name == "identifier"):
                        nodes.check_alive(name)
        fusion.check_alive("attitude_fusion")

    try:
        for processors, _ in heads.values():
            processors.start()
        fusion.start()
        for processors, _ in heads.values():
            processors.wait_ready(START_TIMEOUT_S)
        fusion.wait_ready(START_TIMEOUT_S)
        for _, camera in heads.values():
            camera.start()

        # 1. Both heads: the fused attitude against the truth.
        monitor.spin_until(lambda: len(monitor.statuses_since(0, "head1,head2")) >= BOTH_FUSED, START_TIMEOUT_S,
                           f"{BOTH_FUSED} fusions of both heads", check_alive)
        both = monitor.statuses_since(0, "head1,head2")

        # 2. head2's identifier killed: head2 goes stale, the fusion goes on from head1 alone.
        killed_at = len(monitor.status)
        assert heads["head2"][0].kill("identifier", signal.SIGKILL) == -signal.SIGKILL
        monitor.spin_until(lambda: len(monitor.statuses_since(killed_at, "head1")) >= ALONE_FUSED, PHASE_TIMEOUT_S,
                           "fusions from head1 alone after head2's identifier was killed", check_alive)
        alone = monitor.statuses_since(killed_at, "head1")

        # 3. Restarted: head2 is re-admitted (counted) and both heads are fused again.
        heads["head2"][0].restart("identifier", START_TIMEOUT_S)
        restarted_at = len(monitor.status)
        monitor.spin_until(lambda: monitor.statuses_since(restarted_at, "head1,head2")
                           and monitor.fusion_counter("head2.readmitted") >= 1, PHASE_TIMEOUT_S,
                           "head2 re-admitted after its identifier restarted", check_alive)
    finally:
        codes = {f"{head}/{name}": code for head, (processors, camera) in heads.items()
                 for nodes in (camera, processors) for name, code in nodes.stop().items()}
        codes.update(fusion.stop())
        monitor.destroy_node()
    logs = {p.relative_to(tmp_path): p.read_text(errors="replace") for p in (tmp_path / "logs").rglob("*.log")}
    assert all(code == 0 for code in codes.values()), (codes, logs)
    assert not any("Traceback" in text for text in logs.values()), logs
    assert "outputs flushed: every subscriber acknowledged" in logs[Path("logs/attitude_fusion.log")]

    # The truth: each head's camera renders the body through its mounting (at rest: one attitude).
    for head in HEADS:
        assert monitor.truth[head], head
        for truth in monitor.truth[head].values():
            assert np.degrees(np.linalg.norm(error_body(truth, head_attitude(head)))) * 3600 < 1e-3

    # Accuracy of the fused attitude (body axes) and of each head alone (its own axes: z = roll).
    fused_error = np.array([error_body(monitor.fused[stamp][0], BODY) for stamp, _ in both]) / ARCSEC
    head_error = {head: np.array([error_body(r, head_attitude(head)) for r in monitor.solutions[head].values()])
                  / ARCSEC for head in HEADS}
    rms = {name: np.sqrt(np.mean(e ** 2, axis=0)) for name, e in [("fused", fused_error), *head_error.items()]}
    nees = np.mean([e @ np.linalg.solve(monitor.fused[stamp][1] / ARCSEC ** 2, e)
                    for e, (stamp, _) in zip(fused_error, both)])
    sigma = np.sqrt(np.mean([np.diag(monitor.fused[stamp][1]) for stamp, _ in both], axis=0)) / ARCSEC
    print(f"\nfused RMS error per body axis [\"]: {np.round(rms['fused'], 2)} (stated 1-sigma {np.round(sigma, 2)}, "
          f"NEES {nees:.2f}, {len(both)} fusions); head1 alone (x, y, roll) {np.round(rms['head1'], 2)}, "
          f"head2 alone {np.round(rms['head2'], 2)}")
    assert np.all(np.abs(fused_error) < 5.0), fused_error  # within a few arcsec, every fusion, every axis
    assert nees < 6.0  # the stated covariance holds the errors (3 on average)
    # Body X is head2's roll axis and body Z head1's: each is seen across the other head's
    # boresight. Body Z rests on head2 through its mounting correction, known to the 1" prior
    # at first, so it gains less than body X.
    assert rms["fused"][0] < 0.3 * rms["head2"][2], rms
    assert rms["fused"][2] < 0.6 * rms["head1"][2], rms
    # The fused attitude published on both topics agrees.
    for stamp, _ in both:
        assert np.allclose(monitor.fused_quaternions[stamp], monitor.fused[stamp][0], atol=1e-9)

    # head2 lost: reported stale while head1 alone is fused; then re-admitted, and counted.
    for _, status in alone:
        assert status["head/head2"]["state"] == "stale", status["head/head2"]
        assert status["head/head1"]["state"] == "contributing"
        assert status["fused"]["level"] == DiagnosticStatus.WARN
    alone_error = np.array([error_body(monitor.fused[stamp][0], BODY) for stamp, _ in alone]) / ARCSEC
    print(f"a fusion_status of head1 alone: {alone[-1]}")
    print(f"head1 alone: {len(alone)} fusions, max |error| per body axis [\"] "
          f"{np.round(np.abs(alone_error).max(0), 2)}; counters: head2.stale {monitor.fusion_counter('head2.stale')}, "
          f"head2.readmitted {monitor.fusion_counter('head2.readmitted')}")
    assert monitor.fusion_counter("head2.stale") >= ALONE_FUSED
    after_restart = [s["head/head2"]["state"] for _, s in monitor.status[restarted_at:]]
    assert after_restart[-1] == "contributing", after_restart
    # Counted once per return (a host stall that makes a head miss the window counts as well).
    assert monitor.fusion_counter("head2.readmitted") >= 1
    assert np.all(np.abs(alone_error[:, :2]) < 5.0)  # head1 alone still holds its cross-boresight axes

    # The alignment filter ran on both heads' solutions and stays consistent with the exact mountings.
    assert monitor.alignment
    correction, covariance = monitor.alignment[-1][1:]
    print(f"head2 mounting correction {np.round(correction / ARCSEC, 3)}\" +- "
          f"{np.round(np.sqrt(np.diag(covariance)) / ARCSEC, 3)}\" after {len(monitor.alignment)} updates")
    assert np.all(np.abs(correction) <= 4.0 * np.sqrt(np.diag(covariance)) + 0.3 * ARCSEC)


@pytest.mark.parametrize("params, message", [
    ({"heads": []}, "heads is empty"),
    ({"mounting.head2": [0.5, 0.5, 0.5, 0.4]}, "mounting.head2=[0.5, 0.5, 0.5, 0.4] is not a unit quaternion"),
], ids=["no_heads", "mounting_not_unit"])
def test_bad_parameters_are_refused_at_configure_and_the_node_stays_unconfigured(
        ros_graph, tmp_path, monkeypatch, params, message):
    fusion = NodeProcesses(ros_graph, tmp_path / "logs", {"attitude_fusion": {"autostart": False, **params}},
                           nodes=("attitude_fusion",))
    try:
        fusion.start()
        fusion.wait_ready(START_TIMEOUT_S)
        assert fusion.change_state("attitude_fusion", "configure") is False
        assert fusion.get_state("attitude_fusion") == "unconfigured"
    finally:
        codes = fusion.stop()
    log = fusion.log_paths["attitude_fusion"].read_text()
    assert codes == {"attitude_fusion": 0}, log
    assert f"configure failed: ValueError: {message}" in log, log
    assert "Traceback" not in log


def synthetic_stars(camera, rotation: np.ndarray, count: int = 20, seed: int = 0) -> np.ndarray:
    """Return matched_stars records of `count` stars a head at `rotation` (head -> ICRS) sees exactly (sigma 1")."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(20, camera.width - 20, count), rng.uniform(20, camera.height - 20, count)
    stars = np.zeros(count, convert.MATCH_DTYPE)
    stars["x"], stars["y"], stars["z"] = (camera.pixel_to_ray(u, v) @ rotation.T).T
    stars["pixel_x"], stars["pixel_y"], stars["sigma"] = u, v, ARCSEC
    stars["hip_id"] = np.arange(count)
    return stars


def test_bad_head_input_is_counted_reported_and_left_out(ros_graph, tmp_path, monkeypatch, nominal_camera):
    """
    The fusion node fed by this test: every kind of unusable head solution, and the fusion going on.

    head2 before its camera_info, head2 out of order, head1 malformed, head2 stale: each counted
    per head and its state in fusion_status, while the other head is still fused. Then the
    lifecycle: a solution while inactive is counted and ignored; after cleanup and configure the
    node starts afresh.
    """
    from sensor_msgs.msg import CameraInfo, PointCloud2
    from star_tracker.ros.qos import RESULT_QOS

    fusion = NodeProcesses(ros_graph, tmp_path / "logs", {"attitude_fusion": {"body_rate.source": "none",
                                                                              "alignment.enabled": False}},
                           nodes=("attitude_fusion",))
    monitor = FusionMonitor()
    info = {h: monitor.create_publisher(CameraInfo, f"{h}/camera_info", RESULT_QOS) for h in HEADS}
    matched = {h: monitor.create_publisher(PointCloud2, f"{h}/matched_stars", RESULT_QOS) for h in HEADS}
    stars = {h: synthetic_stars(nominal_camera, head_attitude(h), seed=i) for i, h in enumerate(HEADS)}
    t0 = 1_000_000_000_000

    def send(head: str, stamp_ns: int, records=None) -> None:
        matched[head].publish(convert.records_to_cloud(stars[head] if records is None else records,
                                                       convert.MATCH_FIELDS, stamp_ns, "icrs"))

    def fused_count() -> int:
        return len([s for _, s in monitor.status if s["fused"].get("heads_used")])

    def spin(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(monitor, timeout_sec=0.05)

    try:
        fusion.start()
        fusion.wait_ready(START_TIMEOUT_S)
        monitor.spin_until(lambda: all(p.get_subscription_count() for p in [*info.values(), *matched.values()]),
                           PHASE_TIMEOUT_S, "the fusion node subscribed")
        send("head2", t0)  # before any head2 camera_info
        monitor.spin_until(lambda: monitor.fusion_counter("head2.missing_camera_info") == 1, PHASE_TIMEOUT_S,
                           "head2's solution without camera_info counted")
        for _ in range(5):  # a best-effort subscription: sent a few times
            for head in HEADS:
                info[head].publish(convert.camera_to_info(nominal_camera, t0, f"{head}_optical"))
            spin(0.2)
        send("head1", t0 + 100_000_000)
        monitor.spin_until(lambda: fused_count() == 1, PHASE_TIMEOUT_S, "head1 fused")
        first = monitor.status[-1][1]
        send("head2", t0 + 110_000_000)  # fused with head1's, 10 ms older
        monitor.spin_until(lambda: fused_count() == 2, PHASE_TIMEOUT_S, "both heads fused")
        both = monitor.status[-1][1]
        send("head2", t0 + 105_000_000)  # older than head2's last: out of order
        malformed = PointCloud2(height=1, width=1, point_step=8, row_step=8, data=bytes(8))
        malformed.header.stamp = convert.ns_to_stamp(t0 + 300_000_000)
        matched["head1"].publish(malformed)
        send("head1", t0 + 900_000_000)  # head2's latest is 0.79 s older: stale
        monitor.spin_until(lambda: monitor.fusion_counter("head1.malformed") == 1
                           and monitor.fusion_counter("head2.out_of_order") == 1
                           and monitor.fusion_counter("head2.stale") >= 1, PHASE_TIMEOUT_S, "the refusals counted")
        last = monitor.status[-1][1]
        counters = dict(monitor.diagnostics["star_tracker/attitude_fusion"])
        # The lifecycle: inactive, a solution is counted and ignored; cleaned up and configured
        # again, the node fuses from a fresh start.
        assert fusion.change_state("attitude_fusion", "deactivate")
        send("head1", t0 + 1_000_000_000)
        monitor.spin_until(lambda: monitor.fusion_counter("solutions_ignored_inactive") == 1, PHASE_TIMEOUT_S,
                           "a solution ignored while inactive")
        for transition in ("cleanup", "configure", "activate"):
            assert fusion.change_state("attitude_fusion", transition), transition
        fused_before, stamp = fused_count(), t0 + 2_000_000_000
        end = time.monotonic() + PHASE_TIMEOUT_S
        while fused_count() == fused_before:  # camera_info is best effort: until one got through
            assert time.monotonic() < end, "no fusion after cleanup, configure and activate"
            for head in HEADS:
                info[head].publish(convert.camera_to_info(nominal_camera, t0, f"{head}_optical"))
            spin(0.3)
            send("head2", stamp)
            stamp += 100_000_000
            spin(0.5)
        after_restart = monitor.status[-1][1]
    finally:
        codes = fusion.stop()
        monitor.destroy_node()
    log = fusion.log_paths["attitude_fusion"].read_text()
    assert codes == {"attitude_fusion": 0} and "Traceback" not in log, log
    assert first["head/head2"]["state"] == "missing camera_info" and first["fused"]["heads_used"] == "head1"
    assert both["fused"]["heads_used"] == "head1,head2" and both["head/head1"]["offset_s"] == "+0.010000"
    # head2's latest solution refused, its accepted one stale
    assert last["head/head2"]["state"] == "excluded" and last["fused"]["heads_used"] == "head1", last
    reason = last["head/head2"]["reason"]
    assert reason.count("is not after") == 1 and "latest observation +0.790 s from the stamp" in reason, reason
    # Exact inputs: the fused attitude is the truth to float32 precision, with both heads and alone.
    for stamp in monitor.fused:
        assert np.linalg.norm(error_body(monitor.fused[stamp][0], BODY)) < 0.05 * ARCSEC
    # Per head: received = accepted + refused.
    assert counters["head1.solutions_received"] == "3" and counters["head1.solutions_accepted"] == "2", counters
    assert counters["head2.solutions_received"] == "3" and counters["head2.solutions_accepted"] == "1", counters
    assert counters["fusions_published"] == "3", counters
    # After cleanup and configure: head2 fused alone, head1 never seen since (no solution).
    assert after_restart["fused"]["heads_used"] == "head2", after_restart
    assert after_restart["head/head1"]["state"] == "no solution", after_restart
