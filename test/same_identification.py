# SPDX-License-Identifier: Apache-2.0
"""
One comparison for the compiled one-call paths and the Python steps they stand in for.

test/identify/test_solve_kernel.py (lost-in-space) and test/track/test_recognize_kernel.py
(a tracked frame): two Identifications of the same frame must agree field by field, arrays
and floats bit for bit, the elapsed time aside.
"""
from __future__ import annotations

import numpy as np


def assert_same(fused, steps):
    """Every field of two Identifications equal, arrays and floats bit for bit (elapsed time aside)."""
    for name in ("status", "reason", "algorithm", "hypotheses", "false_positive_probability", "stats"):
        assert getattr(fused, name) == getattr(steps, name), name
    for name in ("spot_index", "hip", "star_vectors", "body_vectors", "residual_rad", "magnitude", "deep"):
        assert np.array_equal(getattr(fused, name), getattr(steps, name)), name
    assert (fused.attitude is None) == (steps.attitude is None)
    if fused.attitude is not None:
        for name in ("quaternion", "rotation", "covariance"):
            assert np.array_equal(getattr(fused.attitude, name), getattr(steps.attitude, name)), name
        assert fused.attitude.loss == steps.attitude.loss


def count_verdicts(monkeypatch, module, name: str) -> dict:
    """
    Count the verdicts of a one-call kernel (`module`.`name`, its result's first entry), call by call.

    Returns the counts by verdict, filled as the test runs (the branch each frame took).
    """
    counts = {}
    kernel = getattr(module, name)

    def counted(*args):
        result = kernel(*args)
        counts[result[0]] = counts.get(result[0], 0) + 1
        return result

    monkeypatch.setattr(module, name, counted)
    return counts
