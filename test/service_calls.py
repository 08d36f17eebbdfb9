# SPDX-License-Identifier: Apache-2.0
"""
Service calls whose answers cannot be lost (for the integration tests).

A Fast DDS service sends its answer after a bounded wait for the caller's response reader
(ros2/rmw_fastrtps#390); on a loaded host the first call of a fresh client can outlast that
wait, and the answer is lost although the call was served. A request that changes nothing
(or changes nothing more when repeated, such as ~/reset) is simply sent again: `answered`. A
parameter change cannot be: the node would count a refused one twice
(`parameter_changes_rejected`). So every service of a parameter client is first asked
something that changes nothing (an empty request: no parameter callback runs), again until
answered; once one answer has arrived, the server has matched this client's reader and later
answers reach it: `primed_parameter_client`.
"""
from __future__ import annotations

import time

import rclpy
from rclpy.node import Node
from rclpy.parameter_client import AsyncParameterClient

ANSWER_WAIT_S = 10.0  # per request; a served request is answered in milliseconds
ATTEMPTS = 3


def answered(node: Node, send, wait_s: float = ANSWER_WAIT_S, attempts: int = ATTEMPTS):
    """
    Return the answer to `send()` (which sends one request and returns its future).

    Sent again when unanswered after wait_s [s], up to `attempts` times: only for requests that
    change nothing, or nothing more when repeated. AssertionError when none is answered.
    """
    for _ in range(attempts):
        future = send()
        end = time.monotonic() + wait_s
        while not future.done() and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.02)
        if future.done():
            return future.result()
    raise AssertionError(f"no answer to {attempts} requests of {wait_s} s each")


def primed_parameter_client(node: Node, target: str, timeout_s: float = 20.0) -> AsyncParameterClient:
    """Return a parameter client of `node` on node `target`, each of its services answered once."""
    client = AsyncParameterClient(node, target)
    assert client.wait_for_services(timeout_sec=timeout_s), f"{target}'s parameter services not found"
    for send in (lambda: client.list_parameters([], 1), lambda: client.get_parameters([]),
                 lambda: client.describe_parameters([]), lambda: client.get_parameter_types([]),
                 lambda: client.set_parameters([]), lambda: client.set_parameters_atomically([])):
        answered(node, send)
    return client
