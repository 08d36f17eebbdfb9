# SPDX-License-Identifier: Apache-2.0
"""
What the orbit demo watches: each head's truth, attitude, status and odometry, and the fused attitude, by stamp.

Head h's topics are /h/truth/attitude, /h/attitude, /h/status and /h/truth/odometry; the
fusion's /attitude. A fused attitude's truth is the body attitude of the head whose solution
it was fused at (that head's truth at the same stamp, R_body = R_head M^T with its mounting).
"""
from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import QuaternionStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node

from ..models.attitude import matrix_to_rotation_vector, quaternion_to_matrix
from ..ros import convert, leo_scenario
from ..ros.pipeline import MONITOR_RESULT_QOS


class OrbitMonitor(Node):
    """Per head and stamp: truth, attitude, status, position; per fused stamp: the fused rotation (module docstring)."""

    def __init__(self, heads: list[str]):
        super().__init__("star_tracker_orbit_monitor")
        self.heads = heads
        self.frames: dict[str, dict[int, dict]] = {h: {} for h in heads}
        self._fused: dict[int, np.ndarray] = {}
        for head in heads:
            self._subscribe(head, QuaternionStamped, "truth/attitude", "truth", _rotation)
            self._subscribe(head, QuaternionStamped, "attitude", "attitude", _rotation)
            self._subscribe(head, DiagnosticArray, "status", "status", lambda m: m.status[0].message)
            self._subscribe(head, Odometry, "truth/odometry", "position", _position)
        self.create_subscription(QuaternionStamped, "/attitude", self._on_fused, MONITOR_RESULT_QOS)

    def _subscribe(self, head: str, kind, topic: str, key: str, decode) -> None:
        def store(msg):
            stamp = convert.stamp_to_ns(msg.header.stamp)
            self.frames[head].setdefault(stamp, {"stamp_ns": stamp})[key] = decode(msg)

        self.create_subscription(kind, f"/{head}/{topic}", store, MONITOR_RESULT_QOS)

    def _on_fused(self, msg: QuaternionStamped) -> None:
        self._fused[convert.stamp_to_ns(msg.header.stamp)] = _rotation(msg)

    @property
    def fused(self) -> dict[int, dict]:
        """Return the fused attitudes by stamp, each with its body truth and error per body axis [rad] where known."""
        out = {}
        for stamp, rotation in self._fused.items():
            row = {"stamp_ns": stamp, "rotation": rotation, "truth": None}
            for head in self.heads:
                truth = self.frames[head].get(stamp, {}).get("truth")
                if truth is not None:
                    mounting = quaternion_to_matrix(np.asarray(leo_scenario.LEO_MOUNTINGS[head]))  # head -> body
                    row["truth"] = truth @ mounting.T
                    row["axis_error"] = matrix_to_rotation_vector(row["truth"].T @ rotation)
                    break
            out[stamp] = row
        return out

    def covered_s(self) -> float:
        """Return the orbit time the slowest head's truth covers [s]."""
        spans = []
        for head in self.heads:
            stamps = [k for k, v in self.frames[head].items() if "truth" in v]
            spans.append((max(stamps) - min(stamps)) * 1e-9 if stamps else 0.0)
        return min(spans)

    def progress_line(self, covered_s: float) -> str:
        """Return a line: orbit time covered, each head's attitudes and its latest status, fusions so far."""
        parts = []
        for head in self.heads:
            rows = self.frames[head]
            solved = sum(1 for v in rows.values() if "attitude" in v)
            latest = max((k for k, v in rows.items() if "status" in v), default=None)
            parts.append(f"{head} {solved}/{sum(1 for v in rows.values() if 'truth' in v)} "
                         f"({rows[latest]['status'] if latest is not None else '-'})")
        return f"orbit time +{covered_s:6.0f} s: " + ", ".join(parts) + f", fused {len(self._fused)}"


def _rotation(msg: QuaternionStamped) -> np.ndarray:
    return quaternion_to_matrix(convert.quaternion_from_msg(msg))


def _position(msg: Odometry) -> np.ndarray:
    p = msg.pose.pose.position
    return np.array([p.x, p.y, p.z])
