# SPDX-License-Identifier: Apache-2.0
"""When the fusion node fuses (fuse/schedule.py): synchronised heads at their stamp, a missing head not awaited long."""
from __future__ import annotations

from star_tracker.fuse.schedule import FusionSchedule

S = 1_000_000_000


def test_synchronised_heads_are_fused_once_both_reported():
    schedule = FusionSchedule()
    assert schedule.add(S, {"a": S}, awaited=["a", "b"]) == []  # b's solution of S not yet here
    assert schedule.pending_ns == S
    assert schedule.add(S, {"a": S, "b": S}, awaited=["a", "b"]) == [S]
    assert schedule.pending_ns is None and schedule.is_old(S)


def test_a_newer_solution_closes_the_waiting_stamp():
    schedule = FusionSchedule()
    schedule.add(S, {"a": S, "b": S - 3 * S}, awaited=["a", "b"])
    assert schedule.add(2 * S, {"a": 2 * S, "b": S - 3 * S}, awaited=["a", "b"]) == [S]  # b missed S
    assert schedule.pending_ns == 2 * S  # and 2S waits in turn


def test_an_older_solution_joins_the_pending_or_the_next_fusion():
    schedule = FusionSchedule()
    schedule.add(2 * S, {"a": 2 * S}, awaited=["a", "b"])
    assert schedule.add(S, {"a": 2 * S, "b": S}, awaited=["a", "b"]) == []  # b at S < 2S: still waiting
    assert schedule.add(2 * S, {"a": 2 * S, "b": 2 * S}, awaited=["a", "b"]) == [2 * S]
    assert schedule.is_old(S) and schedule.add(S, {"a": 2 * S, "b": 2 * S}, awaited=["a", "b"]) == []


def test_the_wait_runs_out_and_nothing_awaited_fuses_at_once():
    schedule = FusionSchedule()
    schedule.add(S, {"a": S}, awaited=["a", "b"])
    assert schedule.expire() == S and schedule.expire() is None
    assert schedule.add(2 * S, {"a": 2 * S}, awaited=[]) == [2 * S]
    schedule.reset()
    assert not schedule.is_old(S)


def test_a_head_late_for_one_fusion_is_awaited_at_the_next():
    """Head b's solution of S came after S was fused without it: b is in step, so 2S waits for it."""
    schedule = FusionSchedule()
    schedule.add(S, {"a": S, "b": 0}, awaited=["a"])  # b not awaited (left out of the fusion before)
    assert schedule.is_old(S)
    assert schedule.awaited({"a": S, "b": S}, contributing=["a"]) == ["a", "b"]  # b's S arrived late
    assert schedule.awaited({"a": S, "b": 0}, contributing=["a"]) == ["a"]  # b silent (blinded): not awaited
    assert schedule.add(2 * S, {"a": 2 * S, "b": S}, awaited=["a", "b"]) == []
    assert schedule.add(2 * S, {"a": 2 * S, "b": 2 * S}, awaited=["a", "b"]) == [2 * S]
