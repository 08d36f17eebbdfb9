# SPDX-License-Identifier: Apache-2.0
"""
The hand-off of decoded frames from a node's executor to its worker thread.

Newest frame wins, and every frame dropped for a newer one is counted and logged.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from typing import TYPE_CHECKING, Callable

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node

if TYPE_CHECKING:  # annotations only
    from .diagnostics import Diagnostics
    from .throttled_log import ThrottledLog


class NewestFrame:
    """
    Newest-frame-wins hand-off from the executor to one worker thread.

    The subscription callback only checks and decodes a message and `put`s it here: it keeps
    up with any input rate, so the DDS queue never overflows (which would drop frames without
    a trace). Up to `depth` frames wait, oldest first (default 1: the worker always takes the
    newest). When a frame arrives and `depth` are waiting, the oldest waiting one is dropped,
    counted as `frames_dropped_overload` on /diagnostics and logged (throttled). Latency stays
    bounded: `depth` waiting frames plus the one in progress.
    """

    def __init__(self, node: Node, process: Callable[[object], None], diag: "Diagnostics", log: "ThrottledLog",
                 depth: int = 1, merge: Callable[[object, object], object] | None = None):
        """
        process(item) runs on the worker thread.

        merge(dropped, next) -> the item to keep in place of `next`, for state a dropped frame
        must hand on (a time reset).
        """
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
        """Return True once nothing waits and the worker is idle."""
        with self._condition:
            return self._condition.wait_for(lambda: not self._waiting and self._idle, timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Let the frame in progress finish (at most timeout_s), drop the waiting ones."""
        with self._condition:
            self._stopping = True
            self._condition.notify_all()
        self._thread.join(timeout_s)
