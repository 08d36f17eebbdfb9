# SPDX-License-Identifier: Apache-2.0
"""
Tests of saturation.box_maxima.

The brightest pixel of many boxes at once, exactly as np.argmax on each box (ties: the first
in row-major order), for small boxes gathered together and large ones read one by one.
"""
import numpy as np
import pytest

from star_tracker.centroid.detection.saturation import BOX_WINDOW_PX, box_maxima


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
def test_box_maxima_equal_argmax_on_each_box(dtype):
    rng = np.random.default_rng(3)
    for _ in range(40):
        height, width = rng.integers(5, 90, 2)
        image = rng.integers(0, 5, (height, width)).astype(dtype)  # few levels: many ties
        n = int(rng.integers(1, 40))
        top, left = rng.integers(0, height, n), rng.integers(0, width, n)
        bottom = np.minimum(top + rng.integers(0, 2 * BOX_WINDOW_PX, n), height)
        right = np.minimum(left + rng.integers(0, 2 * BOX_WINDOW_PX, n), width)
        value, row, col = box_maxima(image, top, left, bottom, right)
        for k in range(n):
            box = image[top[k]:bottom[k], left[k]:right[k]]
            if box.size == 0:
                assert value[k] == -np.inf
                continue
            r, c = np.unravel_index(int(np.argmax(box)), box.shape)
            assert (value[k], row[k], col[k]) == (box[r, c], top[k] + r, left[k] + c)


def test_box_maxima_of_no_boxes():
    value, row, col = box_maxima(np.zeros((8, 8)), *(np.zeros(0, np.int64),) * 4)
    assert value.size == row.size == col.size == 0
