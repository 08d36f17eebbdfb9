# SPDX-License-Identifier: Apache-2.0
"""Log throttling: at most one line per key and kind of message per period, with the count of suppressed repeats."""
from __future__ import annotations

import re
import threading
import time
from collections import Counter
from typing import Callable

from rclpy.node import Node

_NUMBERS = re.compile(r"[-+]?(\d[\d.eE+-]*|nan|inf)")


class ThrottledLog:
    """
    At most one log line per key and kind of message per period, with the count of suppressed repeats.

    Messages differing only in their numbers are of one kind: a stream of the same fault
    logs once per period, while a different fault still gets its line.
    """

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
        """Return the line to write now, or None (counted as suppressed)."""
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
