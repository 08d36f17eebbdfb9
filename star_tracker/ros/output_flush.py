# SPDX-License-Identifier: Apache-2.0
"""
Reliable outputs delivered before their publishers go.

A reliable message not yet acknowledged when its publisher is destroyed, or its process exits,
is lost to any subscriber still waiting for it (a retransmission needs the writer). A node
stopping or cleaning up waits, bounded, for every subscriber to acknowledge what it sent,
and logs the outcome either way. Best-effort publishers have nothing to wait for.
"""
from __future__ import annotations

import time

from rclpy.duration import Duration
from rclpy.qos import ReliabilityPolicy

FLUSH_TIMEOUT_S = 1.0  # [s] the longest a stopping node waits for acknowledgements, all its outputs together


def flush_publishers(node, publishers: dict, timeout_s: float = FLUSH_TIMEOUT_S) -> bool:
    """
    Wait up to timeout_s [s] until every subscriber acknowledged what `publishers` sent; log the outcome.

    publishers: topic name -> rclpy Publisher (None entries and best-effort ones, which nothing
    acknowledges, are skipped). Returns whether all were acknowledged; False without waiting
    once the node's context is shut down.
    """
    publishers = {name: pub for name, pub in publishers.items()
                  if pub is not None and pub.qos_profile.reliability != ReliabilityPolicy.BEST_EFFORT}
    if not publishers:
        return True
    names = ", ".join(publishers)
    if not node.context.ok():
        node.get_logger().warning(f"outputs not flushed ({names}): the context was shut down first")
        return False
    started = time.monotonic()
    pending = [name for name, pub in publishers.items() if not pub.wait_for_all_acked(
        Duration(nanoseconds=int(max(0.0, started + timeout_s - time.monotonic()) * 1e9)))]
    if pending:
        node.get_logger().warning(f"outputs not acknowledged by every subscriber within {timeout_s:.1f} s "
                                  f"({', '.join(pending)}): their last messages may be lost")
        return False
    node.get_logger().info(f"outputs flushed: every subscriber acknowledged {names} "
                           f"(waited {(time.monotonic() - started) * 1e3:.0f} ms)")
    return True
