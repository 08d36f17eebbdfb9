# SPDX-License-Identifier: Apache-2.0
"""
Noise of coarsely quantised frames: the robust noise estimate must not collapse to zero.

A 12-bit camera at 16 e-/ADU: pixel noise below one ADU, most pixels equal to the median.
Then an unclipped standard deviation, inflated by hot pixels, set the threshold 8x too high
and no star was detected. Frames made here, not by our simulator.
"""
import numpy as np

from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid.detection.detect import robust_sigma

GAIN_E_PER_ADU, READ_E, SKY_E, BIAS_ADU = 16.0, 5.0, 20.0, 10.0


def quantised_frame(rng, stars_xy, flux_e=1000.0, sigma_px=1.0, shape=(512, 512), hot_pixels=50):
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    electrons = np.full(shape, SKY_E)
    for x, y in stars_xy:
        electrons += flux_e / (2 * np.pi * sigma_px ** 2) * np.exp(-((xx - x) ** 2 + (yy - y) ** 2)
                                                                   / (2 * sigma_px ** 2))
    signal = rng.poisson(electrons) + rng.normal(0.0, READ_E, shape)
    adu = np.clip(np.round(signal / GAIN_E_PER_ADU + BIAS_ADU), 0, 4095).astype(np.uint16)
    adu.flat[rng.choice(adu.size, hot_pixels, replace=False)] = 4000
    return adu


def test_robust_sigma_of_quantised_noise_is_not_zero():
    rng = np.random.default_rng(1)
    values = np.round(rng.normal(11.25, 0.42, 100_000))
    values[:200] = 4000.0  # hot pixels
    assert 0.42 <= robust_sigma(values) <= 0.6  # the noise plus the quantisation's 1/12 ADU^2


def test_stars_of_a_coarsely_quantised_frame_are_found():
    rng = np.random.default_rng(0)
    stars = rng.uniform(20, 490, (40, 2))
    spots = extract_spots(quantised_frame(rng, stars), CentroidConfig())
    true_noise_adu = np.sqrt(SKY_E + READ_E ** 2) / GAIN_E_PER_ADU
    assert 0.8 * true_noise_adu < spots.noise_adu < 2.0 * true_noise_adu
    nearest = np.hypot(spots.x[:, None] - stars[:, 0], spots.y[:, None] - stars[:, 1]).min(axis=0)
    assert np.sum(nearest < 1.0) >= 36  # of 40 stars at SNR ~20
