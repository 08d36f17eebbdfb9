# SPDX-License-Identifier: Apache-2.0
"""
Connected components' statistics and footprint maxima, compiled (numba).

One pass over the label image: OpenCV's WithStats variant is slower for the few, small
components of a star field.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..kernel_image import WARM_IMAGE_DTYPES


@njit(cache=True)
def component_stats(labels: np.ndarray, count: int):
    """
    Bounding box, pixel count and centroid of each label of a label image, in one pass.

    Box (left, top, right, bottom; exclusive), pixel count and centroid (x, y) of each label
    1..count-1, in one pass
    (OpenCV's WithStats variant is slower for the few, small components of a star field).
    """
    height, width = labels.shape
    left = np.full(count, width, np.int64)
    top = np.full(count, height, np.int64)
    right = np.zeros(count, np.int64)
    bottom = np.zeros(count, np.int64)
    area = np.zeros(count, np.int64)
    sum_x = np.zeros(count)
    sum_y = np.zeros(count)
    for r in range(height):
        for c in range(width):
            k = labels[r, c]
            if k == 0:
                continue
            if c < left[k]:
                left[k] = c
            if c >= right[k]:
                right[k] = c + 1
            if r < top[k]:
                top[k] = r
            if r >= bottom[k]:
                bottom[k] = r + 1
            area[k] += 1
            sum_x[k] += c
            sum_y[k] += r
    return left, top, right, bottom, area, sum_x / np.maximum(area, 1), sum_y / np.maximum(area, 1)


@njit(cache=True)
def footprint_peaks(image: np.ndarray, labels: np.ndarray, binning: int, label: np.ndarray, left: np.ndarray,
                    top: np.ndarray, right: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """
    Highest raw value [ADU] of each detection's footprint pixels (-inf: none).

    labels: the component label image on the binning x binning grid; label, left, top, right,
    bottom: each detection's label and full-resolution bounding box (right/bottom exclusive).
    """
    rows, cols = labels.shape
    out = np.full(label.size, -np.inf)
    for k in range(label.size):
        best = -np.inf
        for r in range(top[k], bottom[k]):
            lr = min(r // binning, rows - 1)
            for c in range(left[k], right[k]):
                if labels[lr, min(c // binning, cols - 1)] == label[k] and image[r, c] > best:
                    best = image[r, c]
        out[k] = best
    return out


def warm_up() -> None:
    """Compile (or load from the cache) both kernels: footprint_peaks for every image dtype it is passed."""
    component_stats(np.zeros((4, 4), np.int32), 1)
    index = np.full(1, 14, np.int64)
    for dtype in WARM_IMAGE_DTYPES:
        footprint_peaks(np.zeros((32, 32), dtype), np.zeros((16, 16), np.int32), 2, np.ones(1, np.int64), index,
                        index, index + 4, index + 4)
