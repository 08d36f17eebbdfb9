# SPDX-License-Identifier: Apache-2.0
"""The integration tests' resend of unanswered no-op requests (test/service_calls.py), on scripted futures."""
from __future__ import annotations

import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.task import Future  # noqa: E402

from service_calls import answered  # noqa: E402


@pytest.fixture
def node():
    rclpy.init(args=[])
    node = rclpy.create_node("service_calls_probe")
    yield node
    node.destroy_node()
    rclpy.try_shutdown()


def scripted(answer_on: int | None):
    """Return send() and its call list: the answer-on-th request is answered ("ok"), the others never."""
    calls = []

    def send():
        calls.append(Future())
        if len(calls) == answer_on:
            calls[-1].set_result("ok")
        return calls[-1]
    return send, calls


def test_an_unanswered_request_is_sent_again_until_answered(node):
    send, calls = scripted(answer_on=3)
    assert answered(node, send, wait_s=0.05, attempts=3) == "ok"
    assert len(calls) == 3


def test_no_answer_at_all_fails_after_the_attempts(node):
    send, calls = scripted(answer_on=None)
    with pytest.raises(AssertionError, match="no answer to 2 requests"):
        answered(node, send, wait_s=0.05, attempts=2)
    assert len(calls) == 2
