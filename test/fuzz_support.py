# SPDX-License-Identifier: Apache-2.0
"""
Shared pieces of the property-based (hypothesis) tests over everything that sees external data.

Test/ros/test_fuzz.py (message converters) and the *_fuzz.py files of the core packages
(test/models, test/centroid, test/identify, test/track). The property is always the same: a
valid result, or ValueError with a message; never another exception (IndexError,
ZeroDivisionError, LinAlgError, numba errors, ...).

Examples are derandomized (the same inputs every run, so CI cannot flake); set
STAR_TRACKER_FUZZ_RANDOM=1 to explore new ones. Defects found are pinned by regression tests
beside the properties, each with its failing input (docs/RELIABILITY.md, "Fuzzing").
"""
from __future__ import annotations

import os

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")

from hypothesis import HealthCheck, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from star_tracker.models.camera import CameraModel  # noqa: E402

FUZZ = settings(deadline=None, derandomize=not os.environ.get("STAR_TRACKER_FUZZ_RANDOM"), database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])


def examples(n: int):
    return settings(FUZZ, max_examples=n)


# Floats as a faulty producer sends them: plausible values, edge values, NaN and infinities.
anything = st.floats(allow_nan=True, allow_infinity=True, width=64)
edgy = st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-300, -1e-300, 1e300, -1e300, np.nan, np.inf, -np.inf])
some_float = st.one_of(anything, edgy, st.floats(-2000.0, 2000.0))
uint32 = st.one_of(st.integers(0, 16), st.integers(0, 2**32 - 1), st.sampled_from([2**31, 2**32 - 1]))

# The identifier's lenses: 15 deg field of view, without and with distortion.
CAMERAS = {"nominal": CameraModel.from_fov(1024, 1024, np.radians(15.0)),
           "distorted": CameraModel.from_fov(1024, 1024, np.radians(15.0), (-0.1, 0.02, 1e-4, -1e-4, 0.0))}


def is_rotation(matrix: np.ndarray) -> bool:
    return (matrix.shape == (3, 3) and bool(np.all(np.isfinite(matrix)))
            and np.allclose(matrix @ matrix.T, np.eye(3), atol=1e-9) and np.linalg.det(matrix) > 0)


def valid_or_value_error(function, *args, **kwargs):
    """
    function(*args) or None when it raised ValueError (with a message).

    Anything else fails, LinAlgError too (numpy derives it from ValueError, but it is a
    failure, not a refusal).
    """
    try:
        return function(*args, **kwargs)
    except np.linalg.LinAlgError:
        raise
    except ValueError as exc:
        assert str(exc), f"{function.__name__} raised ValueError without a message"
        return None


def refused(function, *args, match: str, **kwargs) -> None:
    """
    Assert that function(*args) refuses with a ValueError matching `match` (a regex).

    Not a LinAlgError, and it does not silently return.
    """
    with pytest.raises(ValueError, match=match) as refusal:
        function(*args, **kwargs)
    assert not isinstance(refusal.value, np.linalg.LinAlgError), f"{function.__name__}: {refusal.value!r}"
