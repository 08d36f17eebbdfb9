# SPDX-License-Identifier: Apache-2.0
"""
The background of stars as wide as a background tile (detect.background_tiles).

A wide star's aperture sums the tile median's error over hundreds of pixels: it is taken over
3x3 tiles then. Checked against the known sky of flat and sloped frames, and on the two
defocused-annulus stars (sigma 3 px, SNR 11) that the single-tile background lost in the
PSF-range benchmark's frames (bench/alt_renderer.py, not our simulator).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import alt_renderer as alt  # noqa: E402
from bench import bench_psf_range as bench  # noqa: E402
from star_tracker.centroid import CentroidConfig, extract_spots  # noqa: E402
from star_tracker.centroid.detection.detect import background_and_noise, background_tiles  # noqa: E402


def test_only_stars_whose_aperture_covers_a_quarter_tile_take_3x3_tiles():
    # pi (3 sigma)^2 >= 32^2 / 4  <=>  sigma >= 3.009 px
    assert background_tiles(2.9, 32) == 1 and background_tiles(3.01, 32) == 3
    assert background_tiles(1.0, 32) == 1 and background_tiles(6.1, 64) == 3 and background_tiles(5.9, 64) == 1
    assert background_tiles(0.0, 32) == 1


def test_3x3_tiles_scatter_less_about_a_known_sky_and_keep_a_slope():
    rng = np.random.default_rng(3)
    rows, cols = np.mgrid[0:384, 0:512]
    sky = 200.0 + 0.05 * cols + 0.03 * rows  # [ADU], a stray-light slope
    image = (sky + rng.normal(0.0, 8.0, sky.shape)).astype(np.float32)
    single, _ = background_and_noise(image, 16)
    smoothed, _ = background_and_noise(image, 16, smooth_tiles=3)
    inner = (slice(48, -48), slice(48, -48))  # the border tiles' medians see fewer neighbours
    error_single = np.std((single - sky)[inner])
    error_smoothed = np.std((smoothed - sky)[inner])
    assert error_smoothed < 0.6 * error_single
    assert abs(np.mean((smoothed - sky)[inner])) < 0.2  # the slope is followed, not flattened


def test_a_frame_too_small_for_3x3_tiles_keeps_single_tiles():
    image = np.random.default_rng(1).normal(100.0, 5.0, (24, 40)).astype(np.float32)
    single, _ = background_and_noise(image, 16)
    smoothed, _ = background_and_noise(image, 16, smooth_tiles=3)
    assert np.array_equal(single, smoothed)


@pytest.mark.parametrize("field", [0, 1])
def test_faint_wide_annulus_stars_are_all_found(field):
    # The benchmark's annulus sigma 3 case, its fields 0 and 1 at 1000 e- (rendered after the
    # 300 e- frame of the same field, as bench_psf_range.measure_alt does). One star of each
    # (SNR 11.3) was lost with a single tile's background: its aperture sum 1.3 ADU x 440 px low.
    psf = alt.AnnulusPsf.with_equivalent_sigma(3.0)
    rng = np.random.default_rng([1717, field])
    star_field = bench.alt_star_field(psf, rng)
    frames = {flux: alt.render(star_field, flux, bench.ALT_DETECTOR, bench.ALT_SIZE, bench.ALT_SIZE, rng)
              for flux in (300.0, 1000.0)}
    frame = frames[1000.0]
    spots = extract_spots(frame.image, CentroidConfig())
    assert spots.psf.sigma_px > 3.01  # the estimate, wide enough for 3x3 tiles
    truth = frame.truth
    clear = ~(np.hypot(truth.x[:, None] - truth.defect_x[None], truth.y[:, None] - truth.defect_y[None])
              < 3 * 3.0 + 3 + 0.5 * truth.defect_extent_px[None]).any(axis=1)
    bright = clear & (truth.snr >= 10.0)
    distance = np.hypot(truth.x[:, None] - spots.x[None], truth.y[:, None] - spots.y[None]).min(axis=1)
    assert bright.sum() >= 40
    assert np.all(distance[bright] < 2 * 3.0 + 1), np.flatnonzero(bright & (distance >= 7.0))
