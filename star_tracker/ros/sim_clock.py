# SPDX-License-Identifier: Apache-2.0
"""
A simulated clock on /clock, running `speed` times faster than the wall clock: a scenario in orbit in minutes.

Nodes started with `use_sim_time: true` read their time (timers, stamps, the camera's
exposures) from it. The clock starts at `start_unix_s` (the orbit's time line) and ticks every
`tick_s` of wall time, so a node's timer fires at most `tick_s * speed` of simulated time late.
Each exposure is still simulated at the true body rate: only the frames' clock runs fast.
"""
from __future__ import annotations

import time

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from . import convert

CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)  # as ROS 2's clock publishers


class SimClock(Node):
    """Publishes /clock: start_unix_s + speed x (wall time since the first tick) [s]."""

    def __init__(self, start_unix_s: float, speed: float, tick_s: float = 0.01, name: str = "star_tracker_clock"):
        if not speed > 0:
            raise ValueError(f"speed={speed} must be positive")
        super().__init__(name)
        self.start_ns, self.speed = int(start_unix_s * 1e9), float(speed)
        self._wall0 = time.monotonic()
        self._pub = self.create_publisher(Clock, "/clock", CLOCK_QOS)
        self._timer = self.create_timer(tick_s, self.tick)
        self.tick()

    def now_ns(self) -> int:
        """Return the simulated time now [ns]."""
        return self.start_ns + int((time.monotonic() - self._wall0) * self.speed * 1e9)

    def tick(self) -> None:
        self._pub.publish(Clock(clock=convert.ns_to_stamp(self.now_ns())))
