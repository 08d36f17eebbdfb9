# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker monitor`.

Live terminal view of a running tracker (any ROS 2 graph on this domain: `star-tracker
demo`, `ros2 launch`, or nodes fed from a real camera).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections import deque

import numpy as np

from .common import add_parser, guarded, positive_float

NAME = "monitor"
ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi


def register(subparsers) -> None:
    parser = add_parser(
        subparsers, NAME, "live terminal view of a running tracker: mode, stars, attitude, rate, latency, drops",
        "Subscribe to the identifier's outputs (attitude, attitude_with_covariance, angular_velocity, "
        "matched_stars) and to /diagnostics of all three nodes, and redraw a compact status every "
        "--interval seconds: tracking mode, stars matched, boresight RA/Dec/roll with its 1-sigma, body "
        "rate [deg/s], latency (mid-exposure stamp -> attitude received here), and frame counters with "
        "the frames lost between the nodes (from their /diagnostics counters, which each node publishes "
        "once a second: a difference of a frame or two is in transit). Uses the current ROS_DOMAIN_ID "
        "and discovery settings, like `ros2 topic echo`. Stop with Ctrl-C.",
        "star-tracker monitor\n"
        "star-tracker monitor --namespace st1 --duration 60\n"
        "star-tracker monitor --once 5 --json      # one snapshot after 5 s, machine-readable")
    parser.add_argument("--namespace", default="", metavar="NS",
                        help="namespace of the tracker's topics (default: none, as `star-tracker demo` and the "
                             "launch file without namespace:=...)")
    parser.add_argument("--interval", type=positive_float, default=1.0, metavar="S",
                        help="seconds between redraws (default 1)")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S",
                        help="stop after S seconds (default: until Ctrl-C)")
    parser.add_argument("--once", type=positive_float, nargs="?", const=3.0, default=None, metavar="S",
                        help="listen S seconds (default 3), print one snapshot and exit: exit code 0 if the "
                             "identifier was seen, 1 if nothing was")
    parser.add_argument("--json", action="store_true",
                        help="print snapshots as JSON (one object per line) instead of the text view")
    parser.add_argument("--no-clear", action="store_true",
                        help="append snapshots instead of redrawing the screen (default: redraw on a terminal)")
    parser.set_defaults(func=run)


class TrackerStatus:
    """What the monitor knows: the newest identifier outputs and every node's diagnostics."""

    def __init__(self, history: int = 20):
        self.started = time.monotonic()
        self.attitude = None  # (stamp_ns, rotation)
        self.covariance = None  # 3x3 [rad^2]
        self.rate = None  # (3,) [rad/s]
        self.matched = None  # (count, residual rms [arcsec])
        self.latencies = deque(maxlen=history)  # [s]
        self.attitude_times = deque(maxlen=history)  # monotonic receive times
        self.diagnostics: dict[str, dict] = {}  # status name -> {level, message, values}
        self.messages = 0

    def node_status(self, node: str) -> dict | None:
        """Diagnostics of `node` (camera_simulator, centroider, identifier) in any namespace."""
        for name, status in self.diagnostics.items():
            if name.startswith("star_tracker/") and name.rsplit("/", 1)[-1] == node:
                return status
        return None

    def snapshot(self, namespace: str = "") -> dict:
        from ..models.attitude import matrix_to_radec_roll

        identifier = self.node_status("identifier") or {}
        centroider = self.node_status("centroider") or {}
        camera = self.node_status("camera_simulator") or {}
        values = {node: (status or {}).get("values", {}) for node, status in
                  (("identifier", identifier), ("centroider", centroider), ("camera_simulator", camera))}
        out = {"elapsed_s": round(time.monotonic() - self.started, 2), "namespace": namespace or "/",
               "ros_domain_id": int(os.environ.get("ROS_DOMAIN_ID", "0") or 0),
               "identifier_seen": bool(identifier) or self.attitude is not None,
               "mode": values["identifier"].get("mode"), "algorithm": values["identifier"].get("algorithm"),
               "identifier_message": identifier.get("message"),
               "stars_matched": None, "residual_rms_arcsec": None, "ra_deg": None, "dec_deg": None, "roll_deg": None,
               "attitude_stamp_s": None, "sigma_arcsec": None, "rate_deg_s": None, "attitude_rate_hz": None,
               "latency_ms": None, "latency_ms_median": None,
               "processing_ms": _number(values["identifier"].get("last_processing_ms")),
               "counters": {node: {k: int(v) for k, v in vals.items() if _is_int(v)} for node, vals in values.items()},
               "drops": None}
        if self.attitude is not None:
            stamp_ns, rotation = self.attitude
            ra, dec, roll = (math.degrees(a) for a in matrix_to_radec_roll(rotation))
            out.update(ra_deg=ra, dec_deg=dec, roll_deg=roll, attitude_stamp_s=stamp_ns * 1e-9)
        if self.covariance is not None:
            sigma = np.sqrt(np.maximum(np.diag(self.covariance), 0.0)) * ARCSEC_PER_RAD
            out["sigma_arcsec"] = {"x": float(sigma[0]), "y": float(sigma[1]), "roll": float(sigma[2]),
                                   "cross_boresight": float(math.hypot(sigma[0], sigma[1]))}
        if self.rate is not None:
            out["rate_deg_s"] = [float(w) for w in np.degrees(self.rate)]
        if self.matched is not None:
            out["stars_matched"], out["residual_rms_arcsec"] = self.matched
        if self.latencies:
            out["latency_ms"] = self.latencies[-1] * 1e3
            out["latency_ms_median"] = float(np.median(self.latencies)) * 1e3
        if len(self.attitude_times) >= 2 and self.attitude_times[-1] > self.attitude_times[0]:
            out["attitude_rate_hz"] = (len(self.attitude_times) - 1) / (self.attitude_times[-1]
                                                                        - self.attitude_times[0])
        counters = out["counters"]
        published = counters["camera_simulator"].get("frames_published")
        received = counters["centroider"].get("frames_received")
        processed = counters["centroider"].get("frames_processed")
        identifier_received = counters["identifier"].get("frames_received")
        drops = {}
        if published is not None and received is not None:
            drops["camera_to_centroider"] = max(published - received, 0)
        if processed is not None and identifier_received is not None:
            drops["centroider_to_identifier"] = max(processed - identifier_received, 0)
        if "frames_skipped_overrun" in counters["camera_simulator"]:
            drops["camera_skipped_overrun"] = counters["camera_simulator"]["frames_skipped_overrun"]
        out["drops"] = drops or None
        return out


def _is_int(text) -> bool:
    try:
        int(text)
        return True
    except (TypeError, ValueError):
        return False


def _number(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def format_snapshot(s: dict) -> str:
    def fmt(value, spec, unit=""):
        return "-" if value is None else f"{value:{spec}}{unit}"

    lines = [f"star tracker monitor  namespace {s['namespace']}  ROS_DOMAIN_ID {s['ros_domain_id']}  "
             f"{time.strftime('%H:%M:%S')}  ({s['elapsed_s']:.0f} s)"]
    if not s["identifier_seen"]:
        lines.append("waiting for the identifier (no /diagnostics from it, no attitude yet)")
    mode = s["mode"] or "-"
    lines.append(f"mode        {mode}" + (f" ({s['algorithm']})" if s["algorithm"] else "")
                 + (f"  - {s['identifier_message']}" if s["identifier_message"] else ""))
    if s["ra_deg"] is not None:
        sigma = s["sigma_arcsec"]
        lines.append(f"attitude    RA {s['ra_deg']:9.5f}°  Dec {s['dec_deg']:+9.5f}°  roll {s['roll_deg']:+9.4f}°"
                     + (f"   1σ {sigma['cross_boresight']:.2f}\" cross-boresight, {sigma['roll']:.2f}\" roll"
                        if sigma else "")
                     + f"   stamp {s['attitude_stamp_s']:.3f}"
                     + (f"  ({s['attitude_rate_hz']:.1f} Hz)" if s["attitude_rate_hz"] else ""))
    else:
        lines.append("attitude    -")
    lines.append(f"stars       {fmt(s['stars_matched'], 'd')} matched"
                 + (f", residual RMS {s['residual_rms_arcsec']:.2f}\"" if s["residual_rms_arcsec"] is not None else ""))
    if s["rate_deg_s"] is not None:
        w = s["rate_deg_s"]
        lines.append(f"rate        {w[0]:+.4f} {w[1]:+.4f} {w[2]:+.4f} deg/s (sensor x y z)   "
                     f"|ω| {math.sqrt(sum(v * v for v in w)):.4f} deg/s")
    else:
        lines.append("rate        -")
    lines.append(f"latency     {fmt(s['latency_ms'], '.0f', ' ms')} (median {fmt(s['latency_ms_median'], '.0f', ' ms')}"
                 f" of the last {20}); identifier processing {fmt(s['processing_ms'], '.1f', ' ms')}")
    c = s["counters"]
    cam, cen, ide = c["camera_simulator"], c["centroider"], c["identifier"]
    # The identifier's frames_received = identified + not_identified_* + without camera_info + rejected.
    other = {k[15:]: v for k, v in sorted(ide.items()) if k.startswith("not_identified_")}
    other.update({name: ide[key] for key, name in (("frames_without_camera_info", "no camera_info"),
                                                   ("frames_rejected", "rejected")) if ide.get(key)})
    lines.append(f"frames      camera {cam.get('frames_published', '-')} published | centroider "
                 f"{cen.get('frames_received', '-')} in, {cen.get('frames_processed', '-')} out, "
                 f"{cen.get('frames_rejected', 0)} rejected | identifier {ide.get('frames_received', '-')} in, "
                 f"{ide.get('frames_identified', '-')} identified"
                 + (f", {sum(other.values())} not ({', '.join(f'{k} {v}' for k, v in other.items())})" if other else "")
                 + (f", {ide['frames_bridged']} bridged" if ide.get("frames_bridged") else ""))
    d = s["drops"] or {}
    lines.append("drops       " + (", ".join(f"{k.replace('_', ' ')} {v}" for k, v in d.items()) if d else "-")
                 + ("   (counters of 1 Hz diagnostics: 1-2 frames may be in transit)" if d else ""))
    return "\n".join(lines)


def make_monitor_node(status: TrackerStatus, namespace: str):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped, Vector3Stamped
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    from ..models.attitude import quaternion_to_matrix
    from ..ros import convert

    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
    node = Node("star_tracker_monitor", namespace=namespace or "/")

    def on_attitude(msg) -> None:
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        status.messages += 1
        status.attitude = (stamp_ns, quaternion_to_matrix(convert.quaternion_from_msg(msg)))
        status.latencies.append(node.get_clock().now().nanoseconds * 1e-9 - stamp_ns * 1e-9)
        status.attitude_times.append(time.monotonic())

    def on_pose(msg) -> None:
        status.covariance = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[3:, 3:]

    def on_rate(msg) -> None:
        status.rate = np.array([msg.vector.x, msg.vector.y, msg.vector.z])

    def on_matched(msg) -> None:
        try:
            records = convert.cloud_to_records(msg, convert.MATCH_FIELDS, convert.MATCH_DTYPE)
        except ValueError:  # another layout (an older identifier's): not this monitor's to read
            status.matched = None
            return
        residual = np.asarray(records["residual"], dtype=float) * ARCSEC_PER_RAD
        status.matched = (int(records.size), float(np.sqrt(np.mean(residual ** 2))) if residual.size else None)

    def on_diagnostics(msg) -> None:
        for item in msg.status:
            status.diagnostics[item.name] = {"level": int.from_bytes(item.level, "little")
                                             if isinstance(item.level, bytes)
                                             else int(item.level), "message": item.message,
                                             "values": {kv.key: kv.value for kv in item.values}}

    node.create_subscription(QuaternionStamped, "attitude", on_attitude, qos)
    node.create_subscription(PoseWithCovarianceStamped, "attitude_with_covariance", on_pose, qos)
    node.create_subscription(Vector3Stamped, "angular_velocity", on_rate, qos)
    node.create_subscription(PointCloud2, "matched_stars", on_matched, qos)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, qos)
    return node


@guarded(NAME)
def run(args: argparse.Namespace) -> int:
    namespace = args.namespace.strip()
    if namespace and not namespace.startswith("/"):
        namespace = "/" + namespace
    try:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
    except ImportError as exc:
        raise ValueError(f"monitor needs rclpy ({exc}); "
                         "run it in the project's .venv or a sourced ROS 2 install") from None
    from ..ros.middleware import configure_middleware

    domain = os.environ.get("ROS_DOMAIN_ID", "0").strip() or "0"
    if not (domain.isdigit() and int(domain) <= 232):  # Fast DDS's default ports end at domain 232
        raise ValueError(f"ROS_DOMAIN_ID={domain!r} must be an integer from 0 to 232")
    configure_middleware(os.environ)
    status = TrackerStatus()
    rclpy.init(args=[])
    node = make_monitor_node(status, namespace)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    clear = sys.stdout.isatty() and not args.no_clear and not args.json and args.once is None
    try:
        if args.once is not None:
            _spin(executor, args.once)
            snapshot = status.snapshot(namespace)
            print(json.dumps(snapshot) if args.json else format_snapshot(snapshot), flush=True)
            if not snapshot["identifier_seen"]:
                print(f"star-tracker monitor: no star tracker seen on ROS_DOMAIN_ID "
                      f"{snapshot['ros_domain_id']} within {args.once:g} s", file=sys.stderr)
                return 1
            return 0
        end = time.monotonic() + args.duration if args.duration else math.inf
        while time.monotonic() < end:
            _spin(executor, min(args.interval, end - time.monotonic()))
            snapshot = status.snapshot(namespace)
            if args.json:
                print(json.dumps(snapshot), flush=True)
            else:
                text = format_snapshot(snapshot)
                print(("\x1b[H\x1b[2J" + text) if clear else text + "\n", flush=True)
        return 0
    except KeyboardInterrupt:
        return 0
    finally:
        executor.remove_node(node)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def _spin(executor, seconds: float) -> None:
    end = time.monotonic() + max(seconds, 0.0)
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=min(0.05, max(end - time.monotonic(), 0.0)))
