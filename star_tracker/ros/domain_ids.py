# SPDX-License-Identifier: Apache-2.0
"""
Which ROS domain ids the private graphs (`star-tracker demo`, the pipeline runner, the tests) draw from.

A random id from 100-199 unless `STAR_TRACKER_DOMAIN_IDS=low-high` (inclusive) names another
range: runs sharing a host can split the ids between them (the test suite gives each
pytest-xdist worker its own part, test/conftest.py). No ROS import: the test configuration
reads it before any node exists.
"""
from __future__ import annotations

import os

DOMAIN_IDS_VARIABLE = "STAR_TRACKER_DOMAIN_IDS"
DEFAULT_DOMAIN_IDS = (100, 199)
MAX_DOMAIN_ID = 232  # the largest id whose UDP ports fit (ROS 2 domain id documentation)


def private_domain_ids(environ: dict[str, str] = os.environ) -> tuple[int, int]:
    """Return the inclusive range random private domain ids come from; ValueError if the variable is malformed."""
    text = environ.get(DOMAIN_IDS_VARIABLE, "").strip()
    if not text:
        return DEFAULT_DOMAIN_IDS
    low, _, high = text.partition("-")
    try:
        ids = (int(low), int(high))
    except ValueError:
        ids = None
    if ids is None or not 0 <= ids[0] <= ids[1] <= MAX_DOMAIN_ID:
        raise ValueError(f"{DOMAIN_IDS_VARIABLE}={text!r} must be 'low-high' with 0 <= low <= high <= {MAX_DOMAIN_ID}")
    return ids
