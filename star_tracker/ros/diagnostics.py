# SPDX-License-Identifier: Apache-2.0
"""
A node's /diagnostics.

Counters, stage timings and latest values (Diagnostics), and the report of one rejected
input (Rejections: counter, WARN status, throttled log line).
"""
from __future__ import annotations

import threading
from collections import Counter, deque
from typing import TYPE_CHECKING

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from .qos import DIAGNOSTICS_QOS, overridable

if TYPE_CHECKING:  # annotations only
    from .throttled_log import ThrottledLog


class Diagnostics:
    """
    Counters, stage timings and the latest state of a node, published on /diagnostics at 1 Hz.

    Thread-safe: a node's worker thread and its executor both report here.
    """

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
        self._pub = node.create_publisher(DiagnosticArray, "/diagnostics", **overridable(DIAGNOSTICS_QOS))
        self._timer = node.create_timer(period_s, self.publish)

    def count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self.counters[key] += n

    def set(self, level: int, message: str, **values) -> None:
        with self._lock:
            self.level, self.message = level, message
            self.values.update({k: str(v) for k, v in values.items()})

    def value(self, key: str, value) -> None:
        """Set one latest value, kept until set again."""
        with self._lock:
            self.values[key] = str(value)

    def time(self, stage: str, seconds: float) -> None:
        """
        One frame's duration of `stage` [s].

        Published as <stage>_ms_p50 and <stage>_ms_max over the last TIMING_WINDOW frames.
        """
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


class Rejections:
    """
    One call per rejected input.

    A counter on /diagnostics, a WARN status with the reason, and a throttled log line
    (ThrottledLog: one per kind of message and period).
    """

    def __init__(self, diag: "Diagnostics", log: "ThrottledLog"):
        self.diag, self.log = diag, log

    def __call__(self, counter: str, text: str, n: int = 1) -> None:
        self.diag.count(counter, n)
        self.diag.set(DiagnosticStatus.WARN, text)
        self.log.warn(counter, text)


# /diagnostics values that are integers but not counters (the latest frame's, the PSF's, the calibration's).
VALUE_PREFIXES = ("last_", "psf_", "calibration_")


def counters_of(values: dict[str, str]) -> dict[str, int]:
    """Return the counters among one status's key/values as received: its integer values but VALUE_PREFIXES."""
    return {key: int(value) for key, value in values.items()
            if value.lstrip("-").isdigit() and not key.startswith(VALUE_PREFIXES)}
