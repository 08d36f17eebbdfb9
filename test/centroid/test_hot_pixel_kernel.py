# SPDX-License-Identifier: Apache-2.0
"""
The compiled hot-pixel test (centroid/detection/hot_pixel_kernel.py, through measure.clean_hot_pixels).

Two checks: on a star frame rendered here with hot pixels injected, the test finds exactly
the injected pixels and leaves every star pixel alone; on random stacks, it gives the same
bits as the OpenCV formulation it replaced (written out below as the reference), float32 and
float64, with and without invalid pixels.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.special import erf

from star_tracker.centroid.detection.measure import clean_hot_pixels, star_peak_to_neighbour_ratio

_CROSS = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], np.uint8)


def opencv_reference(windows: np.ndarray, valid: np.ndarray, noise: float, ratio_limit: float):
    """Clean as the stacked OpenCV pass did: 4-neighbour dilation, threshold, 4-neighbour mean (the code before)."""
    n, rows, cols = windows.shape
    stacked = np.where(valid, windows, 0.0).astype(np.float32).reshape(n * rows, cols)
    brightest = cv2.dilate(stacked, _CROSS, borderType=cv2.BORDER_REPLICATE).reshape(n, rows, cols)
    limit = np.maximum(brightest, np.float32(0.0)) * np.float32(ratio_limit) + np.float32(5.0 * noise)
    hit = (windows > limit) & valid
    hit[:, 0, :] = hit[:, -1, :] = False  # a stacked window's first/last rows see the next window
    mean4 = cv2.filter2D(stacked, -1, _CROSS.astype(np.float32) * 0.25, borderType=cv2.BORDER_REPLICATE)
    return np.where(hit, mean4.reshape(n, rows, cols), windows), hit


def star_frame(rng: np.random.Generator, sigma_px: float, noise: float):
    """Return a 200x240 background-subtracted float32 frame of 40 Gaussian stars with read noise [ADU]."""
    rows, cols = 200, 240
    x, y = rng.uniform(10, cols - 10, 40), rng.uniform(10, rows - 10, 40)
    flux = rng.uniform(2e3, 2e5, 40)
    edge_c, edge_r = np.arange(cols) - 0.5, np.arange(rows) - 0.5
    s = np.sqrt(2.0) * sigma_px
    px = 0.5 * (erf((edge_c[None, :] + 1.0 - x[:, None]) / s) - erf((edge_c[None, :] - x[:, None]) / s))
    py = 0.5 * (erf((edge_r[None, :] + 1.0 - y[:, None]) / s) - erf((edge_r[None, :] - y[:, None]) / s))
    light = np.einsum("k,kr,kc->rc", flux, py, px)
    return (light + rng.normal(0.0, noise, light.shape)).astype(np.float32)


@pytest.mark.parametrize("sigma_px", [0.6, 1.0, 2.5])
def test_finds_exactly_the_injected_hot_pixels(sigma_px):
    rng = np.random.default_rng(int(10 * sigma_px))
    noise = 3.0
    frame = star_frame(rng, sigma_px, noise)
    clean = frame.copy()
    # Hot pixels away from the window's first/last rows and the stars' cores, 30-3000 noise sigmas.
    row, col = rng.integers(2, frame.shape[0] - 2, 60), rng.integers(2, frame.shape[1] - 2, 60)
    quiet = np.abs(clean[row, col]) < 4.0 * noise
    row, col = row[quiet], col[quiet]
    frame[row, col] += rng.uniform(90.0, 9000.0, row.size).astype(np.float32)
    ratio_limit = 2.0 * star_peak_to_neighbour_ratio(sigma_px)

    cleaned, hit = clean_hot_pixels(frame[None], np.ones((1,) + frame.shape, bool), noise, ratio_limit)

    injected = np.zeros(frame.shape, bool)
    injected[row, col] = True
    assert np.array_equal(hit[0], injected)
    assert np.array_equal(cleaned[0][~injected], frame[~injected])  # every star pixel untouched
    mean4 = 0.25 * (frame[row - 1, col] + frame[row + 1, col] + frame[row, col - 1] + frame[row, col + 1])
    assert np.allclose(cleaned[0][row, col], mean4, rtol=1e-6, atol=1e-4)


def test_nothing_hit_returns_the_windows_themselves():
    windows = np.random.default_rng(1).normal(0.0, 1.0, (4, 9, 9))
    cleaned, hit = clean_hot_pixels(windows, np.ones(windows.shape, bool), 1.0, 3.0)
    assert cleaned is windows and not hit.any()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("with_invalid", [False, True])
def test_same_bits_as_the_opencv_pass(dtype, with_invalid):
    rng = np.random.default_rng(7 + with_invalid)
    for _ in range(60):
        n, size = rng.integers(1, 20), rng.integers(3, 24)
        centre = (np.arange(size) - 0.5 * size) ** 2
        star = rng.uniform(0, 300) * np.exp(-(centre[:, None] + centre[None, :]) / rng.uniform(1, 8))
        windows = rng.normal(0.0, 3.0, (n, size, size)) + star
        hot = rng.random(windows.shape) < 0.04
        windows[hot] += rng.uniform(10.0, 800.0, hot.sum())
        valid = rng.random(windows.shape) > (0.25 if with_invalid else 0.0)
        windows = windows.astype(dtype)
        noise, ratio_limit = rng.uniform(0.3, 5.0), rng.uniform(0.8, 12.0)  # < 1: the replicated columns matter

        cleaned, hit = clean_hot_pixels(windows, valid, noise, ratio_limit)
        expected, expected_hit = opencv_reference(windows, valid, noise, ratio_limit)

        assert np.array_equal(hit, expected_hit)
        assert cleaned.dtype == expected.dtype and np.array_equal(cleaned, expected)
