# SPDX-License-Identifier: Apache-2.0
"""
What the node benchmarks share: the nodes' configuration, host and process figures, and the watcher node.

bench_pipeline and bench_soak run camera_simulator -> centroider -> identifier as separate
processes over DDS (star_tracker.ros.pipeline.NodeProcesses); this module holds the parts both
use: the parameter file and demo body rate, CPU and memory figures from /proc, and `Watcher`, the
benchmark's own node that records when each attitude (spots, truth) arrives and the nodes'
diagnostics.
"""
from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "star_tracker.yaml"
BODY_RATE_DEG_S = [0.3, 0.4, 0.05]  # the demo body rate [deg/s]
STATUS = {"camera_simulator": "star_tracker/camera_simulator", "centroider": "star_tracker/centroider",
          "identifier": "star_tracker/identifier"}


def join_private_ros() -> dict[str, str]:
    """
    Put this process on a private localhost DDS domain (the nodes' environment) and start rclpy.

    Returns the environment to start the node processes with (isolated_ros_environment); the
    caller shuts rclpy down (rclpy.try_shutdown()).
    """
    import rclpy

    from star_tracker.ros.pipeline import isolated_ros_environment

    env = isolated_ros_environment()
    for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
        os.environ[key] = env[key]
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    rclpy.init()
    return env


# ----------------------------------------------------------------------------- host figures
def cpu_seconds(pid: int) -> float:
    """Return utime + stime of a process [s]."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rss_mib(pid: int) -> float:
    """Resident set size of a process [MiB] (VmRSS)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def host_cpu() -> np.ndarray:
    """/proc/stat cpu line: user, nice, system, idle, iowait, irq, softirq, steal [ticks]."""
    return np.array([int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:9]], float)


def host_usage(before: np.ndarray, after: np.ndarray) -> dict:
    d = after - before
    total = d.sum()
    return {"busy_percent": 100 * (total - d[3] - d[4] - d[7]) / total, "steal_percent": 100 * d[7] / total}


# ----------------------------------------------------------------------------- the watcher
class Watcher:
    """
    This benchmark's own node: attitude (and spots, truth) receive times, diagnostics.

    Spins in a background thread so the main thread can publish on time.
    """

    def __init__(self, with_truth: bool):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import QuaternionStamped
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import PointCloud2

        from star_tracker.ros import convert
        from star_tracker.ros.pipeline import MONITOR_RESULT_QOS, MONITOR_SENSOR_QOS

        self.convert = convert
        self.node = rclpy.create_node("bench_pipeline_watcher")
        self.lock = threading.Lock()
        self.truth: dict[int, np.ndarray] = {}  # stamp -> quaternion
        self.spots_at: dict[int, int] = {}  # stamp -> receive wall time [ns]
        self.attitude_at: dict[int, int] = {}
        self.attitude: dict[int, np.ndarray] = {}
        self.diagnostics: dict[str, dict[str, str]] = {}
        n = self.node
        n.create_subscription(QuaternionStamped, "attitude", self._on_attitude, MONITOR_RESULT_QOS)
        n.create_subscription(PointCloud2, "spots", self._on_spots, MONITOR_SENSOR_QOS)
        n.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)
        if with_truth:
            n.create_subscription(QuaternionStamped, "truth/attitude", self._on_truth, MONITOR_RESULT_QOS)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self._running = True
        self.thread.start()

    def _spin(self) -> None:
        while self._running:
            self.executor.spin_once(timeout_sec=0.05)

    def _on_attitude(self, msg) -> None:
        now = time.time_ns()
        stamp = self.convert.stamp_to_ns(msg.header.stamp)
        with self.lock:
            self.attitude_at[stamp] = now
            self.attitude[stamp] = self.convert.quaternion_from_msg(msg)

    def _on_spots(self, msg) -> None:
        now = time.time_ns()
        with self.lock:
            self.spots_at[self.convert.stamp_to_ns(msg.header.stamp)] = now

    def _on_truth(self, msg) -> None:
        with self.lock:
            self.truth[self.convert.stamp_to_ns(msg.header.stamp)] = self.convert.quaternion_from_msg(msg)

    def _on_diagnostics(self, msg) -> None:
        with self.lock:
            for status in msg.status:
                self.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}

    def counters(self, node: str) -> dict[str, str]:
        with self.lock:
            return dict(self.diagnostics.get(STATUS[node], {}))

    def wait(self, seconds: float, until) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if until():
                return True
            time.sleep(0.05)
        return until()

    def close(self) -> None:
        self._running = False
        self.thread.join(2.0)
        self.executor.remove_node(self.node)
        self.node.destroy_node()


def counter_delta(before: dict, after: dict, key: str) -> int:
    return int(after.get(key, 0)) - int(before.get(key, 0))


def stage_medians(diag: dict) -> dict[str, float]:
    """<stage>_ms_p50 values of one node's diagnostics [ms]."""
    return {k[:-7]: float(v) for k, v in diag.items() if k.endswith("_ms_p50")}


def latency_stats(latency_ms: np.ndarray) -> dict:
    if latency_ms.size == 0:
        return {"median": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {"median": float(np.median(latency_ms)), "p95": float(np.percentile(latency_ms, 95)),
            "max": float(latency_ms.max())}
