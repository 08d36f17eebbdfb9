# SPDX-License-Identifier: Apache-2.0
"""
The time budget of one identification: a deadline on a chosen clock.

"wall" counts elapsed time (a node's real-time budget: a frame must be answered before the
next); "cpu" counts this process's CPU time, so an offline solve does the same search on an
idle and on a loaded host (the `solve` command, tests, benchmarks of accuracy).
"""
from __future__ import annotations

import time

BUDGET_CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


class Deadline:
    """`budget_s` [s] from now on `clock` ("wall" or "cpu"); passed() says whether it is spent."""

    __slots__ = ("_clock", "at")

    def __init__(self, budget_s: float, clock: str = "wall"):
        if clock not in BUDGET_CLOCKS:
            raise ValueError(f"budget clock {clock!r} must be one of {tuple(BUDGET_CLOCKS)}")
        self._clock = BUDGET_CLOCKS[clock]
        self.at = self._clock() + budget_s

    def passed(self) -> bool:
        return self._clock() > self.at

    def remaining_s(self) -> float:
        return self.at - self._clock()
