# SPDX-License-Identifier: Apache-2.0
"""The range random private ROS domains come from (domain_ids.py) and the heap settled after configure."""
from __future__ import annotations

import gc

import pytest

from star_tracker.ros.domain_ids import DEFAULT_DOMAIN_IDS, DOMAIN_IDS_VARIABLE, private_domain_ids


def test_default_range_without_the_variable():
    assert private_domain_ids({}) == DEFAULT_DOMAIN_IDS == (100, 199)
    assert private_domain_ids({DOMAIN_IDS_VARIABLE: " "}) == DEFAULT_DOMAIN_IDS


def test_a_named_range_is_used_by_the_isolated_environment(monkeypatch):
    pytest.importorskip("rclpy")
    from star_tracker.ros.pipeline import isolated_ros_environment

    assert private_domain_ids({DOMAIN_IDS_VARIABLE: "150-174"}) == (150, 174)
    monkeypatch.setenv(DOMAIN_IDS_VARIABLE, "172-173")
    drawn = {int(isolated_ros_environment()["ROS_DOMAIN_ID"]) for _ in range(200)}
    assert drawn == {172, 173}
    assert isolated_ros_environment(5)["ROS_DOMAIN_ID"] == "5"  # a fixed id is not drawn


@pytest.mark.parametrize("text", ["x", "150", "150-", "-3-10", "20-10", "0-233", "a-b"])
def test_a_malformed_range_is_refused_with_the_variable_named(text):
    with pytest.raises(ValueError, match=DOMAIN_IDS_VARIABLE):
        private_domain_ids({DOMAIN_IDS_VARIABLE: text})


def test_settle_heap_freezes_what_is_alive_and_unfreeze_releases_it():
    pytest.importorskip("rclpy")
    from star_tracker.ros.managed_node import settle_heap

    gc.unfreeze()  # whatever an earlier in-process node froze
    assert gc.get_freeze_count() == 0
    try:
        settle_heap()
        assert gc.get_freeze_count() > 1000  # the interpreter, numpy, rclpy... now exempt
    finally:
        gc.unfreeze()
    assert gc.get_freeze_count() == 0
