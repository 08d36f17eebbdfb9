# SPDX-License-Identifier: Apache-2.0
"""
Each blended peak measured on its own pixels (peak_shape.peak_minor_moments, compiled in peak_shape_kernel.py).

Against the truth: a Gaussian star rendered here beside a one-pixel-wide track, the star's
peak as wide as the truncated Gaussian says and centred on the star, the track's peak thin.
Against the numpy formulation it replaced (written out below): random footprints of 1-4
peaks, the same values to 1e-9 (the sums run in another order; exact ties at the disk's edge,
which that order can flip, are avoided by non-integer peaks on float frames).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import erf

from star_tracker.centroid.tracks.peak_shape import (CENTRE_PASSES, CENTRE_SYSTEMATIC_SIGMAS, MIN_PEAK_RADIUS_PX,
                                                     PEAK_RADIUS_SIGMAS, TRUNCATED_MOMENT, peak_minor_moments)


class FlatGround:
    """The detection's background and noise as peak_minor_moments reads them: a tilted plane [ADU]."""

    def __init__(self, level: float, noise: float):
        self.level, self.noise_adu = level, noise

    def background_at(self, x, y):
        return self.level + 0.01 * np.asarray(x, float) - 0.02 * np.asarray(y, float)


def numpy_reference(image, det, peaks, sigma, gain, centres=True):
    """Measure the peaks as the numpy code before the kernel did: (minor, snr, flux, centre, centre_cov)."""
    height, width = image.shape
    radius = max(MIN_PEAK_RADIUS_PX, PEAK_RADIUS_SIGMAS * sigma)
    half = int(math.ceil(radius))
    k_peaks = len(peaks)
    minor, snr, flux_of = np.zeros(k_peaks), np.zeros(k_peaks), np.zeros(k_peaks)
    centre, centre_cov = peaks.copy(), np.full((k_peaks, 2, 2), np.inf)
    background = det.background_at(peaks[:, 0], peaks[:, 1])

    def own_pixels(k, cx, cy):
        col, row = int(round(cx)), int(round(cy))
        c0, c1, r0, r1 = max(col - half, 0), min(col + half + 1, width), max(row - half, 0), min(row + half + 1, height)
        xx, yy = np.arange(c0, c1, dtype=float)[None, :], np.arange(r0, r1, dtype=float)[:, None]
        distance2 = (xx - cx) ** 2 + (yy - cy) ** 2
        inside = distance2 <= radius * radius
        for j, (qx, qy) in enumerate(peaks):
            if j != k:
                inside &= distance2 < (xx - qx) ** 2 + (yy - qy) ** 2
        return xx, yy, np.where(inside, image[r0:r1, c0:c1] - background[k], 0.0), inside

    for k, (px, py) in enumerate(peaks):
        xx, yy, values, inside = own_pixels(k, px, py)
        flux = values.sum()
        if flux <= 0.0:
            continue
        snr[k] = flux / math.sqrt(np.count_nonzero(inside) * det.noise_adu ** 2 + flux / gain)
        mx, my = (values * xx).sum() / flux, (values * yy).sum() / flux
        sxx, syy = (values * (xx - mx) ** 2).sum() / flux, (values * (yy - my) ** 2).sum() / flux
        sxy = (values * (xx - mx) * (yy - my)).sum() / flux
        minor[k] = 0.5 * (sxx + syy) - math.sqrt(0.25 * (sxx - syy) ** 2 + sxy ** 2)
        if not centres:
            continue
        for _ in range(CENTRE_PASSES):
            xx, yy, values, inside = own_pixels(k, mx, my)
            flux = values.sum()
            if flux <= 0.0:
                break
            mx, my = (values * xx).sum() / flux, (values * yy).sum() / flux
        if flux <= 0.0:
            continue
        centre[k], flux_of[k] = (mx, my), flux
        dx, dy = xx - mx, yy - my
        variance = np.where(inside, np.maximum(values, 0.0) / gain + det.noise_adu ** 2, 0.0)
        centre_cov[k] = (np.array([[(variance * dx * dx).sum(), (variance * dx * dy).sum()],
                                   [(variance * dx * dy).sum(), (variance * dy * dy).sum()]]) / flux ** 2
                         + (CENTRE_SYSTEMATIC_SIGMAS * sigma) ** 2 * np.eye(2))
    return minor, snr, flux_of, centre, centre_cov


def gaussian_star(shape, x, y, flux, sigma):
    """Return a pixel-integrated Gaussian star of `flux` [ADU] at (x, y) [px] on a frame of `shape`."""
    edges_c, edges_r, scale = np.arange(shape[1]) - 0.5, np.arange(shape[0]) - 0.5, math.sqrt(2.0) * sigma
    px = 0.5 * (erf((edges_c + 1.0 - x) / scale) - erf((edges_c - x) / scale))
    py = 0.5 * (erf((edges_r + 1.0 - y) / scale) - erf((edges_r - y) / scale))
    return flux * np.outer(py, px)


def test_a_star_beside_a_track_reads_wide_and_centred_the_track_thin():
    sigma, level, noise = 1.5, 100.0, 2.0
    star_x, star_y = 30.3, 25.6
    image = level + gaussian_star((50, 60), star_x, star_y, 40_000.0, sigma)
    image[18:34, 38] += 3_000.0  # a cosmic-ray track one pixel wide, 8 px beside the star
    image += np.random.default_rng(4).normal(0.0, noise, image.shape)
    det = FlatGround(level, noise)
    det.background_at = lambda x, y: np.full(np.size(x), level)
    shapes = peak_minor_moments(image, det, np.array([[30.0, 26.0], [38.0, 26.0]]), sigma, 1.0)
    assert abs(shapes.minor[0] / (TRUNCATED_MOMENT * sigma ** 2) - 1.0) < 0.1
    assert shapes.minor[1] < 0.3 * TRUNCATED_MOMENT * sigma ** 2
    assert math.hypot(shapes.centre[0, 0] - star_x, shapes.centre[0, 1] - star_y) < 0.05
    assert shapes.snr[0] > 100 and np.all(np.isfinite(shapes.centre_cov[0]))


@pytest.mark.parametrize("centres", [True, False])
def test_same_values_as_the_numpy_formulation(centres):
    rng = np.random.default_rng(11 + centres)
    for _ in range(150):
        shape = (40, 50)
        peaks = np.column_stack([rng.uniform(-1.5, shape[1] + 0.5, 4), rng.uniform(-1.5, shape[0] + 0.5, 4)])
        peaks = peaks[:rng.integers(1, 5)]
        image = rng.normal(100.0, 5.0, shape)
        for px, py in peaks:
            image += gaussian_star(shape, px + rng.normal(0, 0.7), py + rng.normal(0, 0.7), rng.uniform(0, 2e4),
                                   rng.uniform(0.5, 3.0))
        det = FlatGround(100.0, 5.0)
        sigma, gain = rng.uniform(0.5, 3.0), rng.uniform(0.5, 4.0)
        compiled = peak_minor_moments(image, det, peaks, sigma, gain, centres=centres)
        reference = numpy_reference(image, det, peaks, sigma, gain, centres=centres)
        for got, expected in zip(compiled, reference):
            assert np.array_equal(np.isinf(got), np.isinf(expected))
            finite = np.isfinite(expected)
            assert np.allclose(got[finite], expected[finite], rtol=1e-9, atol=1e-9)
