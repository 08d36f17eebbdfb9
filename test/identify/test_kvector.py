# SPDX-License-Identifier: Apache-2.0
import numpy as np
import pytest

from star_tracker.identify.kvector import KVector


def test_kvector_range_equals_brute_force():
    rng = np.random.default_rng(0)
    for _ in range(200):
        values = np.sort(np.round(rng.uniform(0, 1, int(rng.integers(2, 3000))) ** 2, int(rng.integers(1, 6))))
        kv = KVector.build(values)
        for q in range(40):
            lo = values[rng.integers(values.size)] if q % 4 == 0 else rng.uniform(-0.1, 1.1)
            hi = lo if q % 8 == 0 else lo + rng.uniform(-0.01, 0.2)
            start, stop = kv.range(lo, hi)
            expected = np.flatnonzero((values >= lo) & (values <= hi))
            assert stop - start == expected.size
            if expected.size:
                assert start == expected[0] and stop == expected[-1] + 1


def test_kvector_rejects_unsorted_input():
    with pytest.raises(ValueError):
        KVector.build(np.array([0.3, 0.1, 0.2]))
