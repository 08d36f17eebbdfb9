"""What every node shares: parameter declaration with descriptors, diagnostics, QoS, main()."""
from __future__ import annotations

import os
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Callable

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

RESULT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)


def sensor_qos(depth: int) -> QoSProfile:
    """Sensor-data profile (best effort, volatile) with a queue of `depth`. Deeper than the
    profile's 5 so that a process stalled for a moment (CPU steal on a shared host, a slow
    frame) catches up instead of losing what arrived meanwhile; Fast DDS sends large samples
    asynchronously, so writers need the depth as well as readers."""
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                      durability=qos_profile_sensor_data.durability)


IMAGE_QOS = sensor_qos(10)  # image_raw, camera_info: 1 s of frames at 10 Hz (~20 MiB at most)
SPOTS_QOS = sensor_qos(20)


def declare(node: Node, name: str, default, description: str, low=None, high=None,
            read_only: bool = True):
    """Declare a parameter with a descriptor (and range) and return its value.

    Values outside the range are rejected by rclpy at startup with a message naming the
    parameter; read-only parameters cannot be changed while the node runs."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if low is not None and high is not None:
        if isinstance(default, bool):
            pass
        elif isinstance(default, int):
            descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=0)]
        elif isinstance(default, float):
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
    return node.declare_parameter(name, default, descriptor).value


class Diagnostics:
    """Counters and the latest state of a node, published on /diagnostics at 1 Hz."""

    def __init__(self, node: Node, period_s: float = 1.0):
        self.node = node
        # Fully qualified node name: trackers in different namespaces stay distinguishable.
        self.name = "star_tracker" + node.get_fully_qualified_name()
        self.counters: Counter[str] = Counter()
        self.values: dict[str, str] = {}
        self.level = DiagnosticStatus.OK
        self.message = "starting"
        self._pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._timer = node.create_timer(period_s, self.publish)

    def count(self, key: str, n: int = 1) -> None:
        self.counters[key] += n

    def set(self, level: int, message: str, **values) -> None:
        self.level, self.message = level, message
        self.values.update({k: str(v) for k, v in values.items()})

    def publish(self) -> None:
        status = DiagnosticStatus(level=self.level, name=self.name, message=self.message,
                                  hardware_id="star_tracker")
        items = {**{k: str(v) for k, v in sorted(self.counters.items())}, **self.values}
        status.values = [KeyValue(key=k, value=v) for k, v in items.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = [status]
        self._pub.publish(msg)


class ThrottledLog:
    """At most one log line per key per period, with the count of suppressed repeats."""

    def __init__(self, node: Node, period_s: float = 2.0):
        self.node, self.period = node, period_s
        self._last: dict[str, float] = {}
        self._suppressed: Counter[str] = Counter()

    def warn(self, key: str, text: str) -> None:
        now = time.monotonic()
        if now - self._last.get(key, -1e9) >= self.period:
            extra = f" ({self._suppressed[key]} similar suppressed)" if self._suppressed[key] else ""
            self.node.get_logger().warning(text + extra)
            self._last[key] = now
            self._suppressed[key] = 0
        else:
            self._suppressed[key] += 1


FASTDDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")
_PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def configure_middleware(environ=os.environ) -> None:
    """Use star_tracker's Fast DDS profile (large shared-memory segment for 2 MiB frames)
    unless the user chose a profile. Must run before rclpy.init() in every process."""
    if not any(environ.get(name) for name in _PROFILE_VARIABLES):
        environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(FASTDDS_PROFILE)


def run_node(factory: Callable[[], Node], argv: list[str] | None = None) -> int:
    """Init rclpy (SIGINT/SIGTERM shut it down), build the node, spin, clean up. Returns the
    process exit code: 0 on a normal shutdown, 2 when the node could not start."""
    args = sys.argv if argv is None else argv
    configure_middleware()
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = factory()
        node.get_logger().info("ready")
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:  # startup errors: bad parameters, unreadable catalog, ...
        print(f"[star_tracker] fatal: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
        code = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


class CameraInfoInput:
    """The camera model from `camera_info` messages: parsed only when the message changes; an
    invalid one (or one `check` refuses with a reason) is counted as camera_info_rejected on
    /diagnostics, logged, and ignored, keeping the last good model in `camera`."""

    def __init__(self, node: Node, diag: "Diagnostics", log: "ThrottledLog",
                 check: Callable[[object], str | None] | None = None):
        self.node, self.diag, self.log, self.check = node, diag, log, check
        self.camera = None
        self._key = None

    def update(self, msg) -> None:
        from . import convert

        key = (msg.width, msg.height, tuple(msg.k), tuple(msg.d), msg.distortion_model)
        if key == self._key:
            return
        try:
            camera = convert.info_to_camera(msg)
            reason = self.check(camera) if self.check else None
        except ValueError as exc:
            reason = str(exc)
        if reason:
            self.diag.count("camera_info_rejected")
            self.log.warn("bad_info", f"rejected camera_info: {reason}")
            return
        self.camera, self._key = camera, key
        self.node.get_logger().info(f"camera model: {camera.width}x{camera.height} px, fx={camera.fx:.2f} px")
