# SPDX-License-Identifier: Apache-2.0
"""
The compiled free streak fit's model (star_tracker.centroid.streak.free_fit_kernel) against direct evaluation.

Its profiles avoid exp per pixel and its jacobian is computed apart from the model: both are
checked here against the formulas they stand for (the fit's accuracy is test_streak.py's).
"""
import math

import numpy as np
import pytest

from star_tracker.centroid.streak import free_fit_kernel as kernel

SIGMA = 1.2
VAR_EFF = SIGMA ** 2 + 1.0 / 12.0
SCALE = 1.0 / math.sqrt(2.0 * VAR_EFF)


def work_for(rows, cols, nodes):
    """Work arrays for a rows x cols window and up to `nodes` nodes."""
    return kernel._Work(np.empty((nodes, cols)), np.empty((nodes, cols)), np.empty((nodes, rows)),
                        np.empty((nodes, rows)), np.empty(nodes), np.empty((5, cols)), np.empty((6, rows, cols)),
                        np.empty((rows, cols)), np.empty(cols), np.empty(cols), kernel._gaussian_table(SCALE))


def model_and_jacobian(p, rows=30, cols=40, intervals=16):
    work = work_for(rows, cols, intervals + 1)
    kernel._segment_model(np.asarray(p, float), 3.0, 5.0, rows, cols, intervals, SCALE, work)
    kernel._segment_jacobian(np.asarray(p, float), rows, cols, intervals, SCALE, work)
    return work.aug[5].copy(), work.aug[:5].copy()


@pytest.mark.parametrize("centre", [7.3, 0.5, -4.2, 19.0, 31.7, 25.5])
@pytest.mark.parametrize("scale", [SCALE, 0.9, 0.2])
def test_profile_is_the_floored_gaussian(centre, scale):
    count, weight = 26, 0.37
    g, vg = np.empty(count), np.empty(count)
    kernel._profile(centre, scale, weight, count, kernel._gaussian_table(scale), g, vg)
    v = (np.arange(count) - centre) * scale
    expected = weight * np.exp(-np.minimum(v * v, 30.0))
    np.testing.assert_allclose(g, expected, rtol=1e-12, atol=0)
    np.testing.assert_allclose(vg, v * expected, rtol=1e-12, atol=1e-300)


def test_model_is_the_simpson_sum_of_psf_copies():
    xc, yc, flux, length, theta, intervals = 21.4, 17.8, 5000.0, 14.0, 0.6, 16
    model, _ = model_and_jacobian((xc, yc, flux, length, theta), intervals=intervals)
    rows, cols = np.mgrid[0:30, 0:40]
    s = np.arange(intervals + 1) / intervals - 0.5
    w = np.where((s == s[0]) | (s == s[-1]), 1.0, np.where(np.arange(intervals + 1) % 2 == 1, 4.0, 2.0))
    w /= 3.0 * intervals
    expected = np.zeros(rows.shape)
    for sk, wk in zip(s, w):  # window frame: the window's top-left pixel is (3, 5)
        dx = (cols - (xc - 3.0 + length * np.cos(theta) * sk)) * SCALE
        dy = (rows - (yc - 5.0 + length * np.sin(theta) * sk)) * SCALE
        expected += wk * np.exp(-np.minimum(dx * dx, 30.0)) * np.exp(-np.minimum(dy * dy, 30.0))
    expected *= flux / (2.0 * np.pi * VAR_EFF)
    np.testing.assert_allclose(model, expected, rtol=1e-10, atol=1e-12 * expected.max())


@pytest.mark.parametrize("p", [(21.4, 17.8, 5000.0, 14.0, 0.6), (20.0, 18.0, 800.0, 1.5, -2.0)])
def test_jacobian_matches_finite_differences(p):
    _, jacobian = model_and_jacobian(p)
    for i, h in enumerate((1e-5, 1e-5, 1e-2, 1e-5, 1e-6)):  # px, px, ADU, px, rad
        up, down = np.array(p, float), np.array(p, float)
        up[i] += h
        down[i] -= h
        numeric = (model_and_jacobian(up)[0] - model_and_jacobian(down)[0]) / (2 * h)
        np.testing.assert_allclose(jacobian[i], numeric, rtol=0, atol=1e-6 * np.abs(numeric).max())
