"""What every node shares: parameter declaration with descriptors, runtime parameter checks,
diagnostics, input-error reporting, stamp ordering, QoS, main()."""
from __future__ import annotations

import faulthandler
import os
import re
import signal
import sys
import threading
import time
from collections import Counter, deque
from pathlib import Path
from typing import Callable

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
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


def _descriptor_problem(node: Node, param: Parameter) -> str | None:
    """Why rclpy will refuse `param` (undeclared, read-only, wrong type, out of range), or None."""
    if not node.has_parameter(param.name):
        return f"{param.name} is not a parameter of {node.get_name()}"
    descriptor = node.describe_parameter(param.name)
    if descriptor.read_only:
        return f"{param.name} is read-only (set it at startup)"
    if param.type_.value != descriptor.type:
        return f"{param.name} must be of type {Parameter.Type(descriptor.type).name}, got {param.type_.name}"
    ranges = list(descriptor.floating_point_range) + list(descriptor.integer_range)
    if ranges and not (ranges[0].from_value <= param.value <= ranges[0].to_value):  # NaN fails too
        return f"{param.name}={param.value} is outside [{ranges[0].from_value}, {ranges[0].to_value}]"
    return None


def guard_parameter_changes(node: Node, apply: Callable[[dict], str | None], diag: "Diagnostics",
                            log: "ThrottledLog") -> None:
    """Runtime `set_parameters`: rclpy refuses read-only, mistyped and out-of-range values
    itself; `apply(changes)` then checks the new values together (building the new
    configuration) and either applies them, returning None, or returns the reason they are
    refused (a ValueError's message counts as one). A refused request keeps every old value,
    answers the caller with the reason, logs it and counts `parameter_changes_rejected`.
    Call after every parameter is declared."""

    def refused(reason: str) -> None:
        diag.count("parameter_changes_rejected")
        diag.set(DiagnosticStatus.WARN, f"parameter change refused: {reason}")
        log.warn("parameters", f"parameter change refused: {reason}")

    def audit(params: list[Parameter]) -> list[Parameter]:  # sees what rclpy alone will refuse
        problems = [p for p in (_descriptor_problem(node, param) for param in params) if p]
        if problems:
            refused("; ".join(problems))
        return params

    def validate(params: list[Parameter]) -> SetParametersResult:
        changes = {param.name: param.value for param in params}
        try:
            reason = apply(changes)
        except ValueError as exc:
            reason = str(exc)
        if reason:
            refused(reason)
            return SetParametersResult(successful=False, reason=reason)
        node.get_logger().info(f"parameters changed: {changes}")
        return SetParametersResult(successful=True)

    node.add_pre_set_parameters_callback(audit)
    node.add_on_set_parameters_callback(validate)


def report_unknown_parameters(node: Node) -> list[str]:
    """Log the parameter overrides (command line, params file) this node does not declare: a
    misspelled name would otherwise be ignored without a word. Returns their names."""
    overrides = getattr(node, "_parameter_overrides", {})  # rclpy keeps them only privately
    unknown = sorted(name for name in overrides if not node.has_parameter(name))
    if unknown:
        node.get_logger().warning(f"ignored unknown parameter(s): {', '.join(unknown)}")
    return unknown


class Diagnostics:
    """Counters, stage timings and the latest state of a node, published on /diagnostics at
    1 Hz. Thread-safe: a node's worker thread and its executor both report here."""

    TIMING_WINDOW = 100  # frames behind each <stage>_ms_p50 / _max

    def __init__(self, node: Node, period_s: float = 1.0):
        self.node = node
        # Fully qualified node name: trackers in different namespaces stay distinguishable.
        self.name = "star_tracker" + node.get_fully_qualified_name()
        self.counters: Counter[str] = Counter()
        self.values: dict[str, str] = {}
        self.timings: dict[str, deque] = {}
        self.level = DiagnosticStatus.OK
        self.message = "starting"
        self._lock = threading.Lock()
        self._pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._timer = node.create_timer(period_s, self.publish)

    def count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self.counters[key] += n

    def set(self, level: int, message: str, **values) -> None:
        with self._lock:
            self.level, self.message = level, message
            self.values.update({k: str(v) for k, v in values.items()})

    def value(self, key: str, value) -> None:
        """Set one latest value (kept until set again)."""
        with self._lock:
            self.values[key] = str(value)

    def time(self, stage: str, seconds: float) -> None:
        """One frame's duration of `stage` [s]; published as <stage>_ms_p50 and <stage>_ms_max
        over the last TIMING_WINDOW frames."""
        with self._lock:
            self.timings.setdefault(stage, deque(maxlen=self.TIMING_WINDOW)).append(seconds)

    def items(self) -> dict[str, str]:
        """Every key/value as published: counters (sorted), timings, then values."""
        with self._lock:
            items = {k: str(v) for k, v in sorted(self.counters.items())}
            for stage, window in sorted(self.timings.items()):
                ms = np.asarray(window) * 1e3
                items[f"{stage}_ms_p50"], items[f"{stage}_ms_max"] = f"{np.median(ms):.2f}", f"{ms.max():.2f}"
            items.update(self.values)
            return items

    def publish(self) -> None:
        items = self.items()
        with self._lock:
            level, message = self.level, self.message
        status = DiagnosticStatus(level=level, name=self.name, message=message, hardware_id="star_tracker")
        status.values = [KeyValue(key=k, value=v) for k, v in items.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = [status]
        self._pub.publish(msg)


class NewestFrame:
    """Newest-frame-wins hand-off from the executor to one worker thread.

    The subscription callback only checks and decodes a message and `put`s it here: it keeps
    up with any input rate, so the DDS queue never overflows (which would drop frames without
    a trace). Up to `depth` frames wait, oldest first (default 1: the worker always takes the
    newest). When a frame arrives and `depth` are waiting, the oldest waiting one is dropped,
    counted as `frames_dropped_overload` on /diagnostics and logged (throttled). Latency stays
    bounded: `depth` waiting frames plus the one in progress."""

    def __init__(self, node: Node, process: Callable[[object], None], diag: "Diagnostics", log: "ThrottledLog",
                 depth: int = 1, merge: Callable[[object, object], object] | None = None):
        """process(item) runs on the worker thread; merge(dropped, next) -> the item to keep in
        place of `next`, for state a dropped frame must hand on (a time reset)."""
        self.node, self.process, self.diag, self.log = node, process, diag, log
        self.depth = int(depth)
        self.merge = merge or (lambda dropped, following: following)
        self._waiting: deque = deque()  # (item, stamp_ns, perf_counter at put)
        self._stopping = False
        self._idle = True
        self._condition = threading.Condition()
        self._thread = threading.Thread(target=self._run, name=f"{node.get_name()}_worker", daemon=True)
        self._thread.start()

    def put(self, item, stamp_ns: int) -> None:
        dropped = None
        with self._condition:
            self._waiting.append((item, stamp_ns, time.perf_counter()))
            if len(self._waiting) > self.depth:
                dropped = self._waiting.popleft()
                following = self._waiting[0]
                self._waiting[0] = (self.merge(dropped[0], following[0]), following[1], following[2])
            self._condition.notify()
        if dropped is not None:
            self.diag.count("frames_dropped_overload")
            self.log.warn("overload", f"overload: frame {dropped[1] * 1e-9:.6f} s dropped unprocessed for the newer "
                          f"{stamp_ns * 1e-9:.6f} s (newest frame wins)")

    def _run(self) -> None:
        while True:
            with self._condition:
                self._idle = True
                self._condition.notify_all()
                while not self._waiting and not self._stopping:
                    self._condition.wait()
                if self._stopping:
                    return
                item, stamp_ns, queued = self._waiting.popleft()
                self._idle = False
            self.diag.time("wait", time.perf_counter() - queued)
            try:
                self.process(item)
            except Exception as exc:  # process() reports its own errors; this is the last net
                if not self.node.context.ok():
                    return  # shutting down: publishers are gone
                self.diag.count("frames_failed")
                self.diag.set(DiagnosticStatus.ERROR, f"internal error: {type(exc).__name__}: {exc}")
                self.log.error("internal", f"frame {stamp_ns * 1e-9:.6f} failed: {type(exc).__name__}: {exc}")

    def wait_idle(self, timeout_s: float) -> bool:
        """True once nothing waits and the worker is idle."""
        with self._condition:
            return self._condition.wait_for(lambda: not self._waiting and self._idle, timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Let the frame in progress finish (at most timeout_s), drop the waiting ones."""
        with self._condition:
            self._stopping = True
            self._condition.notify_all()
        self._thread.join(timeout_s)


class Rejections:
    """One call per rejected input: a counter on /diagnostics, a WARN status with the reason,
    and a throttled log line (ThrottledLog: one per kind of message and period)."""

    def __init__(self, diag: "Diagnostics", log: "ThrottledLog"):
        self.diag, self.log = diag, log

    def __call__(self, counter: str, text: str, n: int = 1) -> None:
        self.diag.count(counter, n)
        self.diag.set(DiagnosticStatus.WARN, text)
        self.log.warn(counter, text)


STAMP_OK, STAMP_UNSET, STAMP_FUTURE, STAMP_OUT_OF_ORDER, STAMP_RESET = (
    "ok", "unstamped", "from_future", "out_of_order", "time_reset")


class StampOrder:
    """Where a frame's stamp stands against the newest stamp so far and the node's clock.

    unstamped: zero (a header never filled in). from_future: more than `max_future_s` ahead of
    the clock (0 disables; skipped while the clock reads zero, as sim time does before the
    first /clock). out_of_order: not newer than the newest stamp (duplicates included) by at
    most `reset_after_s`. time_reset: older by more than that (a replay or a simulation
    restarted). Only ok and time_reset frames become the newest."""

    def __init__(self, node: Node, max_future_s: float, reset_after_s: float):
        self.node, self.max_future_s, self.reset_after_s = node, max_future_s, reset_after_s
        self.newest_ns: int | None = None
        self._previous_ns: int | None = None  # the newest before the last classify()

    def classify(self, stamp_ns: int) -> str:
        self._previous_ns = self.newest_ns
        if stamp_ns == 0:
            return STAMP_UNSET
        now_ns = self.node.get_clock().now().nanoseconds
        if self.max_future_s > 0 and now_ns > 0 and stamp_ns > now_ns + self.max_future_s * 1e9:
            return STAMP_FUTURE
        verdict = STAMP_OK
        if self.newest_ns is not None and stamp_ns <= self.newest_ns:
            if self.newest_ns - stamp_ns <= self.reset_after_s * 1e9:
                return STAMP_OUT_OF_ORDER
            verdict = STAMP_RESET
        self.newest_ns = stamp_ns
        return verdict

    def describe(self, verdict: str, stamp_ns: int) -> str:
        now_ns = self.node.get_clock().now().nanoseconds
        newest = "none" if self._previous_ns is None else f"{self._previous_ns * 1e-9:.6f} s"
        what = {STAMP_UNSET: "unstamped (zero)", STAMP_RESET: "a jump back in time"}.get(verdict, verdict.replace("_", " "))
        return f"frame stamp {stamp_ns * 1e-9:.6f} s is {what} (newest {newest}, clock {now_ns * 1e-9:.6f} s)"


_NUMBERS = re.compile(r"[-+]?(\d[\d.eE+-]*|nan|inf)")


class ThrottledLog:
    """At most one log line per key and kind of message per period, with the count of
    suppressed repeats. Messages differing only in their numbers are of one kind: a stream
    of the same fault logs once per period, while a different fault still gets its line."""

    def __init__(self, node: Node, period_s: float = 2.0):
        self.node, self.period = node, period_s
        self._last: dict[str, float] = {}
        self._suppressed: Counter[str] = Counter()
        self._lock = threading.Lock()  # a node's worker thread logs too

    def warn(self, key: str, text: str) -> None:
        self._emit(key, text, self.node.get_logger().warning)

    def error(self, key: str, text: str) -> None:
        self._emit(key, text, self.node.get_logger().error)

    def _emit(self, key: str, text: str, write: Callable[[str], object]) -> None:
        with self._lock:
            line = self._line(key, text)
        if line is not None:
            write(line)

    def _line(self, key: str, text: str) -> str | None:
        """The line to write now, or None (counted as suppressed)."""
        key = key + ":" + _NUMBERS.sub("#", text)
        now = time.monotonic()
        if len(self._last) > 256:  # garbage input can make endless kinds: forget the quiet ones
            for stale in [k for k, t in self._last.items() if now - t >= self.period and not self._suppressed[k]]:
                del self._last[stale]
                self._suppressed.pop(stale, None)
        if now - self._last.get(key, -1e9) >= self.period:
            extra = f" ({self._suppressed[key]} similar suppressed)" if self._suppressed[key] else ""
            self._last[key] = now
            self._suppressed[key] = 0
            return text + extra
        self._suppressed[key] += 1
        return None


FASTDDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")
_PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def configure_middleware(environ=os.environ) -> None:
    """Use star_tracker's Fast DDS profile (large shared-memory segment for 2 MiB frames)
    unless the user chose a profile. Must run before rclpy.init() in every process."""
    if not any(environ.get(name) for name in _PROFILE_VARIABLES):
        environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(FASTDDS_PROFILE)


def check_params_files(args: list[str]) -> None:
    """Every `--params-file PATH` must name a readable regular file (rcl's own error is a C
    parser trace)."""
    for i, arg in enumerate(args):
        if arg == "--params-file" or arg.startswith("--params-file="):
            value = arg.partition("=")[2] if "=" in arg else (args[i + 1] if i + 1 < len(args) else "")
            path = Path(value)
            if not value:
                raise ValueError("--params-file needs a path")
            if not path.exists():
                raise ValueError(f"--params-file {value}: no such file")
            if not path.is_file():
                raise ValueError(f"--params-file {value}: not a regular file")
            if not os.access(path, os.R_OK):
                raise ValueError(f"--params-file {value}: not readable")


def check_cache_directory(environ=os.environ) -> None:
    """STAR_TRACKER_CACHE (catalog and pattern-database caches), when set, must be a
    directory this process can read and write, or a path it can create."""
    value = environ.get("STAR_TRACKER_CACHE")
    if not value:
        return
    path = Path(value)
    if path.exists() and not path.is_dir():
        raise ValueError(f"STAR_TRACKER_CACHE={value} is not a directory")
    if path.is_dir() and not os.access(path, os.R_OK | os.W_OK | os.X_OK):
        raise ValueError(f"STAR_TRACKER_CACHE={value} is not readable and writable by this process")


SHUTDOWN_WATCHDOG_S = 10.0  # [s] from the end of the spin to the end of the process


def run_node(factory: Callable[[], Node], argv: list[str] | None = None) -> int:
    """Init rclpy (SIGINT/SIGTERM shut it down), build the node, spin, clean up. Returns the
    process exit code: 0 on a normal shutdown, 2 when the node could not start (bad
    arguments or parameters: one `fatal:` line on stderr, no traceback). A clean-up that
    hangs ends the process after SHUTDOWN_WATCHDOG_S with code 1 and every thread's stack on
    stderr; SIGUSR1 prints those stacks at any time. For a node's own process only (main())."""
    args = sys.argv if argv is None else argv
    configure_middleware()
    node = None
    code = 0
    initialized = spinning = False

    def on_sigint(signum, frame):
        # rclpy's own handler has already shut the context down, which ends the spin cleanly.
        # A KeyboardInterrupt on top would land in whatever Python code the main thread runs,
        # and inside a __del__ it is only printed ("Exception ignored ... Traceback").
        if not spinning:
            raise KeyboardInterrupt  # still starting up: stop now

    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, on_sigint) if main_thread else None
    if main_thread and hasattr(signal, "SIGUSR1"):
        # `kill -USR1 <pid>` prints every thread's stack to stderr, even while the main
        # thread is blocked in C (a node that does not stop, a stuck DDS call).
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        check_params_files(args)
        check_cache_directory()
        rclpy.init(args=args)
        initialized = True
        node = factory()
        report_unknown_parameters(node)
        node.get_logger().info("ready")
        spinning = True
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:  # startup errors: bad parameters, unreadable catalog, ...
        if initialized and not rclpy.ok():
            # SIGINT/SIGTERM shut the context down under a running call (e.g. the executor
            # building its wait set: RCLError "the given context is not valid"): a normal stop.
            pass
        else:
            print(f"[star_tracker] fatal: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
            code = 2
    finally:
        if main_thread:
            # A stop must never hang: past SHUTDOWN_WATCHDOG_S (here or in the interpreter's
            # exit), every thread's stack goes to stderr and the process exits with code 1.
            # A node with longer legitimate work in flight declares it (shutdown_extra_s [s]).
            faulthandler.dump_traceback_later(SHUTDOWN_WATCHDOG_S + getattr(node, "shutdown_extra_s", 0.0), exit=True)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        if main_thread:
            signal.signal(signal.SIGINT, previous)
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
            self.diag.set(DiagnosticStatus.WARN, f"rejected camera_info: {reason}")
            self.log.warn("bad_info", f"rejected camera_info: {reason}")
            return
        self.camera, self._key = camera, key
        self.node.get_logger().info(f"camera model: {camera.width}x{camera.height} px, fx={camera.fx:.2f} px")
