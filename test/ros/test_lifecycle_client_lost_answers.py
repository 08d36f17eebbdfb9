# SPDX-License-Identifier: Apache-2.0
"""
LifecycleClient.change_state when a transition's answer is lost (ros/lifecycle_client.py).

The decision alone, on a stand-in node that answers or drops each call as scripted: no DDS
(the answered path runs over DDS in test_lifecycle_nodes.py). A lost answer is judged by the
node's state: the goal reached is success, the state before means the request is sent again.
"""
from __future__ import annotations

import pytest

from star_tracker.ros import lifecycle_client
from star_tracker.ros.lifecycle_client import LifecycleClient

GOAL = {"activate": ("inactive", "active"), "deactivate": ("active", "inactive")}


class ScriptedNode:
    """A managed node whose change_state answers are dropped `lost` times; transitions valid from their source."""

    def __init__(self, state: str, lost: int):
        self.state, self.lost, self.requests = state, lost, 0

    def change(self, label: str) -> bool:
        self.requests += 1
        source, goal = GOAL[label]
        success = self.state == source
        if success:
            self.state = goal
        return success


def client_for(node: ScriptedNode) -> LifecycleClient:
    client = LifecycleClient.__new__(LifecycleClient)  # no rclpy context: _call and get_state stand in

    def call(node_name, srv_type, suffix, request, timeout_s, discovery_s=0.1):
        success = node.change(request.transition.label)
        if node.lost > 0:
            node.lost -= 1
            return None  # sent and run, the answer lost
        return type("Response", (), {"success": success})()

    client._call = call
    client.get_state = lambda node_name, timeout_s=5.0: node.state
    return client


@pytest.fixture(autouse=True)
def short_waits(monkeypatch):
    monkeypatch.setattr(lifecycle_client, "ANSWER_WAIT_S", 0.05)


def test_a_lost_answer_to_a_transition_that_ran_is_success():
    node = ScriptedNode("inactive", lost=1)
    assert client_for(node).change_state("/identifier", "activate", timeout_s=5.0) is True
    assert node.state == "active" and node.requests == 1  # not requested twice


def test_a_lost_answer_to_a_refused_transition_is_asked_again_and_stays_refused():
    node = ScriptedNode("active", lost=2)  # activate from active: refused
    assert client_for(node).change_state("/identifier", "activate", timeout_s=5.0) is False
    assert node.state == "active" and node.requests == 3


def test_a_transition_that_never_arrived_is_requested_again():
    node = ScriptedNode("active", lost=0)
    client = client_for(node)
    sent = client._call
    dropped = []

    def drop_first(node_name, srv_type, suffix, request, timeout_s, discovery_s=0.1):
        if not dropped:
            dropped.append(request)
            return None  # the request itself lost: the node never ran it
        return sent(node_name, srv_type, suffix, request, timeout_s, discovery_s)

    client._call = drop_first
    assert client.change_state("/identifier", "deactivate", timeout_s=5.0) is True
    assert node.state == "inactive" and node.requests == 1


def test_no_answer_at_all_times_out():
    node = ScriptedNode("inactive", lost=10 ** 6)
    client = client_for(node)
    client.get_state = lambda node_name, timeout_s=5.0: None  # the node answers nothing
    with pytest.raises(TimeoutError, match="no answer to 'activate'"):
        client.change_state("/identifier", "activate", timeout_s=0.5)
