# SPDX-License-Identifier: Apache-2.0
"""
Compiled 4-neighbour hot-pixel test of measure.clean_hot_pixels (numba).

One pass over a stack of windows (n, rows, cols), float32 or float64: a frame-sized window
cost OpenCV and numpy five full-frame passes and their temporaries (2.8-10 ms on a 1280x960
frame, depending on whether those pages were fresh), this 1.4-2 ms. The arithmetic is the
OpenCV pass's, in float32, so the results are the same to the bit: neighbours outside
`valid` read 0, columns replicate at the window's edges, and a window's first and last rows
are never tested (the stacked pass saw the next window there).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _neighbours(windows, valid, all_valid, k, i, j):
    """(up, left, right, down) of pixel (i, j) of window k, float32; invalid ones read 0."""
    cols = windows.shape[2]
    jl = j - 1 if j > 0 else j
    jr = j + 1 if j < cols - 1 else j
    zero = np.float32(0.0)
    if all_valid:
        return (np.float32(windows[k, i - 1, j]), np.float32(windows[k, i, jl]), np.float32(windows[k, i, jr]),
                np.float32(windows[k, i + 1, j]))
    return (np.float32(windows[k, i - 1, j]) if valid[k, i - 1, j] else zero,
            np.float32(windows[k, i, jl]) if valid[k, i, jl] else zero,
            np.float32(windows[k, i, jr]) if valid[k, i, jr] else zero,
            np.float32(windows[k, i + 1, j]) if valid[k, i + 1, j] else zero)


@njit(cache=True, inline="always")
def is_hot(value, up, left, right, down, ratio, floor) -> bool:
    """
    Whether a pixel of `value` [ADU] beside float32 neighbours (up, left, right, down) is hot.

    Brighter than ratio x its brightest neighbour (at least 0) + floor, in float32 (ratio and
    floor float32 [ADU]).
    """
    return value > max(max(max(up, down), max(left, right)), np.float32(0.0)) * ratio + floor


@njit(cache=True, inline="always")
def neighbour_mean(up, left, right, down):
    """Return the float32 mean of the 4 neighbours, summed in OpenCV's order (the same bits as its filter)."""
    return np.float32(0.25) * (((up + left) + right) + down)


@njit(cache=True)
def hot_pixel_hits(windows, valid, all_valid, noise, ratio_limit):
    """
    Return (hit mask, count) of the hot pixels of `windows` [ADU].

    A hit is brighter than ratio_limit x its brightest 4-neighbour (at least 0) + 5 noise [ADU].
    """
    n, rows, cols = windows.shape
    hit = np.zeros(windows.shape, np.bool_)
    ratio = np.float32(ratio_limit)
    floor = np.float32(5.0 * noise)
    count = 0
    for k in range(n):
        for i in range(1, rows - 1):
            for j in range(cols):
                if not all_valid and not valid[k, i, j]:
                    continue
                up, left, right, down = _neighbours(windows, valid, all_valid, k, i, j)
                if is_hot(windows[k, i, j], up, left, right, down, ratio, floor):
                    hit[k, i, j] = True
                    count += 1
    return hit, count


@njit(cache=True)
def replace_hits(windows, valid, all_valid, hit, out):
    """Write the mean of its 4 neighbours (float32) into `out` at each hit of `windows`."""
    n, rows, cols = windows.shape
    for k in range(n):
        for i in range(1, rows - 1):
            for j in range(cols):
                if hit[k, i, j]:
                    up, left, right, down = _neighbours(windows, valid, all_valid, k, i, j)
                    out[k, i, j] = neighbour_mean(up, left, right, down)


def warm_up() -> None:
    """Compile (or load from the cache) both kernels for the float32 and float64 stacks the centroider passes."""
    for dtype in (np.float32, np.float64):
        windows = np.zeros((1, 3, 3), dtype)
        valid = np.ones((1, 3, 3), np.bool_)
        for all_valid in (True, False):
            hit, _ = hot_pixel_hits(windows, valid, all_valid, 1.0, 2.0)
            replace_hits(windows, valid, all_valid, hit, windows.copy())
