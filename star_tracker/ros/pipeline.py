# SPDX-License-Identifier: Apache-2.0
"""
Run the three nodes as separate processes and watch their outputs against truth.

Used by `star-tracker demo` and by the integration tests: real processes, real DDS.
"""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped, TwistWithCovarianceStamped, Vector3Stamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2

from ..models.attitude import attitude_error, quaternion_to_matrix
from . import convert
from .domain_ids import private_domain_ids
from .lifecycle_client import LifecycleClient, wait_for_state
from .middleware import configure_middleware
from .qos import IMAGE_QOS, sensor_qos

# The monitor must see every message: deep queues (it can stall like any process here).
MONITOR_RESULT_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
MONITOR_SENSOR_QOS = sensor_qos(100)

NODE_MODULES = {
    "camera_simulator": "star_tracker.ros.camera_simulator_node",
    "centroider": "star_tracker.ros.centroider_node",
    "identifier": "star_tracker.ros.identifier_node",
    "attitude_fusion": "star_tracker.ros.attitude_fusion_node",
}
HEAD_NODES = ("camera_simulator", "centroider", "identifier")  # one head's chain: what NodeProcesses starts by default


def isolated_ros_environment(domain_id: int | None = None) -> dict[str, str]:
    """
    Environment for a private DDS graph on this host.

    A random domain id (from private_domain_ids()) and localhost-only discovery, plus the Fast
    DDS profile.
    """
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain_id if domain_id is not None else random.randint(*private_domain_ids()))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated in Jazzy; conflicts with the range setting
    configure_middleware(env)
    return env


def parameter_arguments(params: dict[str, object]) -> list[str]:
    """`-p name:=value` arguments in ROS 2 YAML syntax (lists as [a, b])."""
    args = []
    for name, value in params.items():
        if isinstance(value, (list, tuple)):
            text = "[" + ", ".join(repr(float(v)) if isinstance(v, float) else str(v) for v in value) + "]"
        elif isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, float):
            text = repr(value)
        else:
            text = str(value)
        args += ["-p", f"{name}:={text}"]
    return args


class NodeProcesses:
    """The three nodes as child processes (own process groups), logs in `log_dir`."""

    def __init__(self, env: dict[str, str], log_dir: Path, params: dict[str, dict] | None = None,
                 params_files: Path | list[Path] | None = None, nodes: tuple[str, ...] = HEAD_NODES,
                 remaps: dict[str, dict[str, str]] | None = None):
        """
        Describe the node processes to start on the private graph of `env`.

        params_files: ros2 parameter files, later ones overriding earlier ones; `params` (per node
        name) override both; remaps: per node name, topic -> new name (`-r`).
        """
        self.env, self.log_dir = env, Path(log_dir)
        self.remaps = remaps or {}
        self.params = params or {}
        self.params_files = [params_files] if isinstance(params_files, (str, Path)) else list(params_files or [])
        self.nodes = nodes
        self.processes: dict[str, subprocess.Popen] = {}
        self.log_paths: dict[str, Path] = {}  # each node's current log (a restart starts a new one)
        self._logs = {}
        self._launches: dict[str, int] = {}
        self._lifecycle: LifecycleClient | None = None

    def start(self, timeout_s: float = 120.0) -> "NodeProcesses":
        """
        Start the processing nodes, wait until they are active, then start the camera.

        Wait until they are active (configured: compiled kernels loaded, database built; asked
        over ~/get_state), then the camera: no frame is published into a pipeline still
        starting.
        """
        self.log_dir.mkdir(parents=True, exist_ok=True)
        sources = [name for name in self.nodes if name == "camera_simulator"]
        processors = [name for name in self.nodes if name not in sources]
        for name in processors:
            self._launch(name)
        if sources and processors:
            self.wait_ready(timeout_s)
        for name in sources:
            self._launch(name)
        return self

    def _launch(self, name: str) -> None:
        cmd = [sys.executable, "-m", NODE_MODULES[name], "--ros-args"]
        for path in self.params_files:
            cmd += ["--params-file", str(path)]
        cmd += parameter_arguments(self.params.get(name, {}))
        for old, new in self.remaps.get(name, {}).items():
            cmd += ["-r", f"{old}:={new}"]
        n = self._launches[name] = self._launches.get(name, 0) + 1
        self.log_paths[name] = self.log_dir / (f"{name}.log" if n == 1 else f"{name}.restart{n - 1}.log")
        if name in self._logs:
            self._logs[name].close()
        log = open(self.log_paths[name], "w")
        self._logs[name] = log
        self.processes[name] = subprocess.Popen(cmd, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                                stdin=subprocess.DEVNULL, start_new_session=True)

    @property
    def lifecycle(self) -> LifecycleClient:
        """Lifecycle service calls to the nodes (made on first use, closed by stop())."""
        if self._lifecycle is None:
            self._lifecycle = LifecycleClient(self.env)
        return self._lifecycle

    def expected_state(self, name: str) -> str:
        """
        Return the state a node reaches by itself.

        Active, or unconfigured with `autostart: false` among this object's `params`.
        """
        return "unconfigured" if self.params.get(name, {}).get("autostart") is False else "active"

    def node_path(self, name: str) -> str:
        """Return a node's fully qualified name, with its `__ns` / `__node` remaps (e.g. /det/identifier)."""
        remaps = self.remaps.get(name, {})
        namespace = remaps.get("__ns", "").strip("/")
        node = remaps.get("__node", name)
        return f"/{namespace}/{node}" if namespace else f"/{node}"

    def check_alive(self, name: str) -> None:
        """Raise RuntimeError with the node's log if its process has exited."""
        if self.processes[name].poll() is not None:
            text = self.log_paths[name].read_text(errors="replace")
            raise RuntimeError(f"{name} exited with {self.processes[name].returncode}:\n{text}")

    def wait_ready(self, timeout_s: float = 120.0, names=None) -> None:
        """
        Block until every started node (or those in `names`) is in the state it reaches by itself.

        That is, until it answers ~/get_state with that state (active with autostart, the
        default; else unconfigured); raise with its log if one died, TimeoutError if one hung.
        """
        names = list(self.processes if names is None else names)
        for state in sorted({self.expected_state(name) for name in names}):
            paths = {self.node_path(n): n for n in names if self.expected_state(n) == state}
            wait_for_state(self.env, list(paths), state, timeout_s, check=lambda path: self.check_alive(paths[path]))

    def get_state(self, name: str, timeout_s: float = 30.0) -> str | None:
        """
        Return a node's lifecycle state label (None: no answer within timeout_s [s]).

        The client finds the node's service by discovery: on a loaded 2-core host it once took
        longer than 5 s for a node that had answered another client already.
        """
        return self.lifecycle.get_state(self.node_path(name), timeout_s=timeout_s)

    def change_state(self, name: str, transition: str, timeout_s: float = 120.0) -> bool:
        """
        Request a lifecycle transition of a node (configure, activate, deactivate, cleanup, shutdown).

        True if it succeeded.
        """
        self.check_alive(name)
        return self.lifecycle.change_state(self.node_path(name), transition, timeout_s)

    def kill(self, name: str, sig: int = signal.SIGKILL, timeout_s: float = 15.0) -> int:
        """
        Send `sig` to one node and wait for it to exit (SIGKILL after timeout_s).

        Returns its exit code (negative: killed by that signal).
        """
        proc = self.processes[name]
        if proc.poll() is None:
            proc.send_signal(sig)
        try:
            return proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            return proc.wait()

    def launch(self, name: str, timeout_s: float = 120.0) -> None:
        """
        Start one node now (any of NODE_MODULES, with this object's parameters) and wait until it is ready.

        `stop` stops it with the others.
        """
        self._launch(name)
        self.wait_ready(timeout_s, names=[name])

    def restart(self, name: str, timeout_s: float = 120.0) -> None:
        """Start a node again after it exited (its new log: `<name>.restart<n>.log`) and wait until it is ready."""
        if self.processes[name].poll() is None:
            raise RuntimeError(f"{name} is still running")
        self.launch(name, timeout_s)

    def stop(self, timeout_s: float = 15.0, sig: int = signal.SIGINT) -> dict[str, int]:
        """Send `sig` (SIGINT or SIGTERM) to every node, wait, SIGKILL what is left. Returns exit codes."""
        for proc in self.processes.values():
            if proc.poll() is None:
                proc.send_signal(sig)
        deadline = time.monotonic() + timeout_s
        codes = {}
        for name, proc in self.processes.items():
            try:
                codes[name] = proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                # Where it hangs, in its log (run_node dumps every thread's stack on SIGUSR1).
                os.kill(proc.pid, signal.SIGUSR1)
                time.sleep(1.0)
                os.killpg(proc.pid, signal.SIGKILL)
                codes[name] = proc.wait()
        for log in self._logs.values():
            log.close()
        if self._lifecycle is not None:
            self._lifecycle.close()
            self._lifecycle = None
        return codes

    def __enter__(self) -> "NodeProcesses":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


@dataclass
class FrameRecord:
    """Everything seen for one frame (keyed by its mid-exposure stamp)."""

    stamp_ns: int
    first_seen: float = field(default_factory=time.monotonic)
    truth: np.ndarray | None = None  # sensor -> ICRS rotation
    spot_count: int | None = None
    attitude: np.ndarray | None = None
    covariance: np.ndarray | None = None
    attitude_latency_s: float | None = None
    matched: np.ndarray | None = None  # MATCH_DTYPE records
    truth_objects: np.ndarray | None = None  # TRUTH_OBJECT_DTYPE records
    image: np.ndarray | None = None
    truth_rate: np.ndarray | None = None  # (3,) [rad/s], sensor frame
    rate: np.ndarray | None = None  # identifier's estimate (3,) [rad/s]
    rate_covariance: np.ndarray | None = None  # (3, 3) [rad^2/s^2]

    def error(self) -> tuple[float, float, float] | None:
        """(cross-boresight, roll, total) attitude error vs truth [rad]."""
        if self.truth is None or self.attitude is None:
            return None
        return attitude_error(self.attitude, self.truth)


class TrackerMonitor(Node):
    """Subscribes to truth and to every output; joins them by stamp."""

    def __init__(self, keep_images: bool = False, name: str = "star_tracker_monitor"):
        super().__init__(name)
        self.frames: dict[int, FrameRecord] = {}
        self.keep_images = keep_images
        self._executor: SingleThreadedExecutor | None = None
        self.create_subscription(QuaternionStamped, "truth/attitude", self._on_truth, MONITOR_RESULT_QOS)
        self.create_subscription(PointCloud2, "truth/objects", self._on_truth_objects, MONITOR_RESULT_QOS)
        self.create_subscription(PointCloud2, "spots", self._on_spots, MONITOR_SENSOR_QOS)
        self.create_subscription(QuaternionStamped, "attitude", self._on_attitude, MONITOR_RESULT_QOS)
        self.create_subscription(PoseWithCovarianceStamped, "attitude_with_covariance", self._on_pose,
                                 MONITOR_RESULT_QOS)
        self.create_subscription(PointCloud2, "matched_stars", self._on_matches, MONITOR_RESULT_QOS)
        self.create_subscription(Vector3Stamped, "truth/angular_velocity", self._on_truth_rate, MONITOR_RESULT_QOS)
        self.create_subscription(TwistWithCovarianceStamped, "angular_velocity_with_covariance", self._on_rate,
                                 MONITOR_RESULT_QOS)
        self.diagnostics: dict[str, dict[str, str]] = {}  # latest key/values per status name
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self._image_subscription = None
        if keep_images:
            self.enable_images()

    def enable_images(self) -> None:
        """Start keeping images (each costs a 2 MiB copy: subscribe only when one is needed)."""
        if self._image_subscription is None:
            self._image_subscription = self.create_subscription(Image, "image_raw", self._on_image, IMAGE_QOS)

    def frame(self, stamp) -> FrameRecord:
        ns = convert.stamp_to_ns(stamp)
        if ns not in self.frames:
            self.frames[ns] = FrameRecord(ns)
        return self.frames[ns]

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}

    def _on_truth(self, msg: QuaternionStamped) -> None:
        self.frame(msg.header.stamp).truth = quaternion_to_matrix(convert.quaternion_from_msg(msg))

    def _on_truth_rate(self, msg: Vector3Stamped) -> None:
        self.frame(msg.header.stamp).truth_rate = np.array([msg.vector.x, msg.vector.y, msg.vector.z])

    def _on_rate(self, msg: TwistWithCovarianceStamped) -> None:
        record = self.frame(msg.header.stamp)
        w = msg.twist.twist.angular
        record.rate = np.array([w.x, w.y, w.z])
        record.rate_covariance = np.asarray(msg.twist.covariance).reshape(6, 6)[3:, 3:]

    def _on_truth_objects(self, msg: PointCloud2) -> None:
        self.frame(msg.header.stamp).truth_objects = convert.cloud_to_records(
            msg, convert.TRUTH_OBJECT_FIELDS, convert.TRUTH_OBJECT_DTYPE).copy()

    def _on_spots(self, msg: PointCloud2) -> None:
        self.frame(msg.header.stamp).spot_count = int(msg.width) * int(msg.height)

    def _on_attitude(self, msg: QuaternionStamped) -> None:
        record = self.frame(msg.header.stamp)
        record.attitude = quaternion_to_matrix(convert.quaternion_from_msg(msg))
        record.attitude_latency_s = self.get_clock().now().nanoseconds * 1e-9 - record.stamp_ns * 1e-9

    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        self.frame(msg.header.stamp).covariance = np.asarray(msg.pose.covariance).reshape(6, 6)[3:, 3:]

    def _on_matches(self, msg: PointCloud2) -> None:
        self.frame(msg.header.stamp).matched = convert.cloud_to_records(msg, convert.MATCH_FIELDS,
                                                                        convert.MATCH_DTYPE).copy()

    def _on_image(self, msg: Image) -> None:
        record = self.frame(msg.header.stamp)
        record.image = convert.image_to_array(msg)
        # Keep only the newest few images in memory, and the newest identified frame's (the
        # demo's picture: after a host stall the newest images can all be unidentified).
        with_images = sorted(ns for ns, r in self.frames.items() if r.image is not None)
        keep = set(with_images[-8:]) | set([ns for ns in with_images if self.frames[ns].matched is not None][-1:])
        for ns in with_images:
            if ns not in keep:
                self.frames[ns].image = None

    def spin_for(self, seconds: float, until=None) -> bool:
        """
        Process callbacks for `seconds`, or until `until()` is true.

        Returns whether `until()` became true (False without one).
        """
        if self._executor is None:
            self._executor = SingleThreadedExecutor(context=self.context)
            self._executor.add_node(self)
        end = time.monotonic() + seconds
        while time.monotonic() < end and self.context.ok():
            self._executor.spin_once(timeout_sec=0.05)
            if until is not None and until():
                return True
        return until is not None and bool(until())

    def destroy_node(self) -> None:
        if self._executor is not None:
            self._executor.remove_node(self)
            self._executor.shutdown()
            self._executor = None
        super().destroy_node()


def summarize(frames: list[FrameRecord]) -> dict:
    """Identification rate, attitude error statistics [arcsec] and latency [ms]."""
    with_truth = [f for f in frames if f.truth is not None]
    errors = np.array([f.error() for f in with_truth if f.attitude is not None]).reshape(-1, 3)
    arcsec = np.degrees(errors) * 3600.0
    latency = np.array([f.attitude_latency_s for f in with_truth if f.attitude_latency_s is not None])
    identified = int(errors.shape[0])

    def pct(values, q):
        return float(np.percentile(values, q)) if values.size else float("nan")

    return {
        "frames": len(with_truth),
        "frames_with_spots": sum(1 for f in with_truth if f.spot_count is not None),
        "identified": identified,
        "identification_rate": identified / len(with_truth) if with_truth else 0.0,
        "wrong_over_60_arcsec": int(np.sum(arcsec[:, 2] > 60.0)) if identified else 0,
        "cross_boresight_arcsec_median": pct(arcsec[:, 0], 50) if identified else float("nan"),
        "cross_boresight_arcsec_p95": pct(arcsec[:, 0], 95) if identified else float("nan"),
        "roll_arcsec_median": pct(arcsec[:, 1], 50) if identified else float("nan"),
        "roll_arcsec_p95": pct(arcsec[:, 1], 95) if identified else float("nan"),
        "max_error_arcsec": float(arcsec[:, 2].max()) if identified else float("nan"),
        "latency_ms_median": pct(latency * 1e3, 50),
        "latency_ms_max": float(latency.max() * 1e3) if latency.size else float("nan"),
    }
