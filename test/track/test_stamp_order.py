# SPDX-License-Identifier: Apache-2.0
"""StampOrder: the stamp rule the nodes and the stress campaign share, on a settable clock."""
from star_tracker.track.stamp_order import (STAMP_FUTURE, STAMP_OK, STAMP_OUT_OF_ORDER, STAMP_RESET, STAMP_UNSET,
                                            StampOrder)

S = 1_000_000_000


def test_stamps_are_judged_against_the_newest_and_the_clock():
    clock = [10 * S]
    order = StampOrder(lambda: clock[0], max_future_s=1.0, reset_after_s=2.0)
    assert order.classify(0) == STAMP_UNSET
    assert order.classify(10 * S) == STAMP_OK
    assert order.classify(10 * S) == STAMP_OUT_OF_ORDER  # a duplicate
    assert order.classify(9 * S) == STAMP_OUT_OF_ORDER  # 1 s back: within reset_after_s
    assert order.classify(12 * S) == STAMP_FUTURE  # 2 s ahead of the clock
    assert order.newest_ns == 10 * S  # refused frames do not move the newest
    clock[0] = 12 * S
    assert order.classify(12 * S) == STAMP_OK
    assert order.classify(5 * S) == STAMP_RESET  # 7 s back: time restarted
    assert order.newest_ns == 5 * S
    assert "a jump back in time" in order.describe(STAMP_RESET, 5 * S)


def test_the_future_check_is_off_while_the_clock_reads_zero_or_when_disabled():
    assert StampOrder(lambda: 0, 1.0, 2.0).classify(100 * S) == STAMP_OK
    assert StampOrder(lambda: S, 0.0, 2.0).classify(100 * S) == STAMP_OK
