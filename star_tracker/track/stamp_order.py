# SPDX-License-Identifier: Apache-2.0
"""
Stamp policy: where a frame's header stamp stands.

Against the newest stamp so far and a clock: ok, unstamped, from the future, out of order, a
jump back in time. ROS-free: the nodes pass their clock (ros/centroider_node.py,
ros/identifier_node.py) and the stress campaign the simulated one (campaign/presets/stress.py),
so both judge stamps by the same rule.
"""
from __future__ import annotations

from typing import Callable

STAMP_OK, STAMP_UNSET, STAMP_FUTURE, STAMP_OUT_OF_ORDER, STAMP_RESET = (
    "ok", "unstamped", "from_future", "out_of_order", "time_reset")


class StampOrder:
    """
    Where a frame's stamp stands against the newest stamp so far and the clock.

    now_ns: the clock [ns] (0 while unset). unstamped: zero (a header never filled in).
    from_future: more than `max_future_s` [s] ahead of the clock (0 disables; skipped while the
    clock reads zero, as sim time does before the first /clock). out_of_order: not newer than
    the newest stamp (duplicates included) by at most `reset_after_s` [s]. time_reset: older by
    more than that (a replay or a simulation restarted). Only ok and time_reset frames become
    the newest.
    """

    def __init__(self, now_ns: Callable[[], int], max_future_s: float, reset_after_s: float):
        self.now_ns, self.max_future_s, self.reset_after_s = now_ns, max_future_s, reset_after_s
        self.newest_ns: int | None = None
        self._previous_ns: int | None = None  # the newest before the last classify()

    def classify(self, stamp_ns: int) -> str:
        self._previous_ns = self.newest_ns
        if stamp_ns == 0:
            return STAMP_UNSET
        now_ns = self.now_ns()
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
        now_ns = self.now_ns()
        newest = "none" if self._previous_ns is None else f"{self._previous_ns * 1e-9:.6f} s"
        what = {STAMP_UNSET: "unstamped (zero)",
                STAMP_RESET: "a jump back in time"}.get(verdict, verdict.replace("_", " "))
        return f"frame stamp {stamp_ns * 1e-9:.6f} s is {what} (newest {newest}, clock {now_ns * 1e-9:.6f} s)"
