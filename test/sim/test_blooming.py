# SPDX-License-Identifier: Apache-2.0
"""sim.blooming on hand-made columns: the excess spills both ways along the column, conserved until an end."""
from __future__ import annotations

import numpy as np

from star_tracker.sim.blooming import bloom_columns

FULL_WELL = 100.0


def test_excess_spills_half_up_half_down_and_is_conserved():
    image = np.full((21, 3), 10.0, np.float32)
    image[10, 1] = 450.0  # 350 over the full well: 175 each way, 90 of room in each pixel
    before = image.sum()
    bloom_columns(image, FULL_WELL)
    column = image[:, 1]
    assert column[10] == FULL_WELL
    # 175 up: 90 fill the pixel above, 85 the next; the same down.
    assert np.allclose(column[7:14], [10.0, 95.0, 100.0, 100.0, 100.0, 95.0, 10.0])
    assert np.isclose(image.sum(), before)
    assert np.all(image[:, [0, 2]] == 10.0)  # other columns untouched


def test_charge_reaching_the_end_of_a_column_is_lost_and_nothing_exceeds_the_full_well():
    image = np.full((5, 2), 50.0, np.float32)
    image[2, 0] = 1e6
    bloom_columns(image, FULL_WELL)
    assert np.all(image[:, 0] == FULL_WELL) and np.all(image[:, 1] == 50.0)


def test_without_overflow_the_image_is_unchanged():
    image = np.random.default_rng(0).uniform(0, FULL_WELL, (8, 8)).astype(np.float32)
    copy = image.copy()
    bloom_columns(image, FULL_WELL)
    assert np.array_equal(image, copy)
