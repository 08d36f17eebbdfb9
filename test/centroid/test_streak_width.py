# SPDX-License-Identifier: Apache-2.0
"""
The PSF width of a rate-aided frame, measured across its streaks (centroid/streak/streak_width.py).

On streaks of the independent renderer (bench/alt_renderer.py: each streak a line of
pixel-integrated Gaussian stamps, its own noise), and end to end on the simulator's frame that
once was measured at the 1 px prior: a 2.5 px PSF slewing at 1 deg/s, its spots then ~7 times
more uncertain than they stated; and a sparse field of faint streaks whose PSF only one or two
of them show at the 1 px prior, measured again at their width; with no rate known, the
width across each streak's own track; and the width across an undersampled PSF's streaks
(streak/narrow_width.py), which the profile's few bins read 20-30 % narrow.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from bench.alt_renderer import Detector, GaussianPsf, StarField, render
from bench.fingerprints import frame_seed
from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid.streak.narrow_width import streak_pixels
from star_tracker.centroid.streak.streak_width import streak_width
from star_tracker.centroid.streak.smear import SmearModel
from star_tracker.models.camera import CameraModel

from smeared_alt_frames import found, smeared_frame

SIZE = 512


def _alt_streaks(sigma_px: float, rng: np.random.Generator):
    camera = CameraModel.from_fov(SIZE, SIZE, math.radians(8.0))
    smear = SmearModel(camera, np.array([0.024, -0.014, 0.004]), 0.1)
    grid = np.meshgrid(np.linspace(80, 430, 4), np.linspace(80, 430, 4))
    cx, cy = (v.ravel() + rng.uniform(-3, 3, 16) for v in grid)
    vectors = smear.smear_vectors(cx, cy)
    steps = 60
    fractions = (np.arange(steps) + 0.5) / steps - 0.5
    x = (cx[:, None] + fractions[None] * vectors[:, 0:1]).ravel()
    y = (cy[:, None] + fractions[None] * vectors[:, 1:2]).ravel()
    frame = render(StarField.build(GaussianPsf(sigma_px), x, y), 20000.0 / steps, Detector(), SIZE, SIZE, rng)
    return frame.image, cx, cy, smear, float(np.median(np.hypot(*vectors.T)))


@pytest.mark.parametrize("sigma_px", [0.8, 1.5, 2.5])
def test_the_width_across_an_independent_renderers_streaks_is_its_psf(sigma_px):
    image, x, y, smear, length = _alt_streaks(sigma_px, np.random.default_rng(int(sigma_px * 10)))
    assert length > 8.0  # streaks, not points
    width, uncertainty, used = streak_width(image, x, y, np.full(x.size, 100.0), smear)
    assert used >= 5
    assert width == pytest.approx(sigma_px, rel=0.07), (width, uncertainty)


@pytest.mark.parametrize("sigma_px, angle_rad",
                         [(0.4, 0.0), (0.4, 0.3), (0.4, math.pi / 4), (0.4, 3.3), (0.5, 1.2), (0.6, 2.0)])
def test_the_width_across_an_undersampled_psfs_streaks_is_its_psf(sigma_px, angle_rad):
    # 0.4 px streaks smeared 3 px at 3.3 rad read 0.27-0.30 px for every streak of the frame by
    # the log-parabola over the profile's bins (below the fits' 0.3 px: the frame held 1 px).
    frame = smeared_frame(GaussianPsf(sigma_px), 3.0, angle_rad, 3)
    width, _, used = streak_width(frame.image, frame.x, frame.y, np.full(frame.x.size, 100.0), frame.smear)
    assert used >= 5
    assert width == pytest.approx(sigma_px, rel=0.05), width


@pytest.mark.parametrize("smear_px", [3.0, 4.0])
def test_a_cold_rate_aided_frame_of_undersampled_streaks_is_measured_at_its_psf(smear_px):
    # Read 0.28 px across, below the fits' range, the 3 px frame held the configured 1 px and
    # refused its 40 sharp streaks as cosmic-ray tracks (0 spots); read 0.32 px, the 4 px frame
    # split 26 of its 40 streaks.
    frame = smeared_frame(GaussianPsf(0.4), smear_px, 3.3, 3)
    spots = extract_spots(frame.image, CentroidConfig(), frame.smear)
    assert spots.psf.estimated and spots.psf.applied_sigma_px == pytest.approx(0.4, rel=0.05), spots.psf
    stars, stray = found(spots, frame.x, frame.y)
    assert stars == frame.x.size and stray == 0, (stars, stray, len(spots))


@pytest.mark.parametrize("angle_rad", [0.0, 0.5, math.pi / 4])
def test_a_streaks_pixels_hold_its_flux_and_its_pixel_integrated_profile(angle_rad):
    # The unit-flux streak's pixel means sum to 1 (over a window holding all its light) and,
    # along x, its profile across is the normal CDF's difference over each pixel (erf).
    unit = np.array([math.cos(angle_rad), math.sin(angle_rad)])
    cols, rows = np.meshgrid(np.arange(-12, 13), np.arange(-12, 13))
    along = (cols * unit[0] + rows * unit[1]).ravel().astype(float)
    across = (-cols * unit[1] + rows * unit[0]).ravel().astype(float)
    pixels = streak_pixels(along, across, unit, 5.0, 0.4, 0.0, 0.2)
    assert pixels.sum() == pytest.approx(1.0, abs=2e-3)
    if angle_rad == 0.0:
        from scipy.special import ndtr
        centre_column = np.abs(along) < 0.5  # the pixels at the streak's middle, all its length's light along
        expected = (ndtr((across[centre_column] + 0.5 - 0.2) / 0.4) - ndtr((across[centre_column] - 0.5 - 0.2) / 0.4))
        along_light = ndtr(2.5 / 0.4) - ndtr(-2.5 / 0.4)  # the middle pixel's along-track share, times L
        assert np.allclose(pixels[centre_column] * 5.0, expected * along_light, atol=3e-3)


def test_too_few_streaks_give_no_width():
    image, x, y, smear, _ = _alt_streaks(1.5, np.random.default_rng(3))
    width, _, used = streak_width(image, x[:2], y[:2], np.full(2, 100.0), smear)
    assert math.isnan(width) and used == 2


@pytest.mark.parametrize("flux_e, seed", [(3000.0, 2), (2500.0, 5)])
def test_a_sparse_frame_of_faint_wide_streaks_is_measured_at_the_width_its_few_streaks_show(flux_e, seed):
    # Four 10 px streaks of a 2.7 px PSF (independent renderer): at the 1 px prior two of them
    # reach the width measurement's SNR, too few for the frame's width; measured at 1 px the
    # stars were fragments 0.4-1.6 px off. Measured again at those two's width, three streaks
    # give it.
    camera = CameraModel.from_fov(SIZE, SIZE, math.radians(8.0))
    smear = SmearModel(camera, np.array([0.024, -0.014, 0.004]), 0.1)
    rng = np.random.default_rng(seed)
    cx, cy = rng.uniform(60, 450, 4), rng.uniform(60, 450, 4)
    vectors = smear.smear_vectors(cx, cy)
    steps = 60
    fractions = (np.arange(steps) + 0.5) / steps - 0.5
    x = (cx[:, None] + fractions[None] * vectors[:, 0:1]).ravel()
    y = (cy[:, None] + fractions[None] * vectors[:, 1:2]).ravel()
    frame = render(StarField.build(GaussianPsf(2.7), x, y), flux_e / steps, Detector(), SIZE, SIZE, rng)
    spots = extract_spots(frame.image, CentroidConfig(), smear)
    assert spots.psf.estimated and spots.psf.applied_sigma_px == pytest.approx(2.7, rel=0.15), spots.psf
    offsets = [float(np.min(np.hypot(spots.x - a, spots.y - b))) for a, b in zip(cx, cy)]
    assert max(offsets) < 0.3, offsets


@pytest.mark.parametrize("sigma_px", [2.0, 2.8])
def test_without_a_rate_the_psf_is_measured_across_the_streaks_own_tracks(sigma_px):
    # Sixteen 25 px streaks (independent renderer) and no rate: no star is round, so the
    # round-star estimate held the 1 px prior; at 2.8 px no spot at all was kept.
    camera = CameraModel.from_fov(SIZE, SIZE, math.radians(8.0))
    smear = SmearModel(camera, 2.5 * np.array([0.024, -0.014, 0.004]), 0.1)
    rng = np.random.default_rng(2)
    grid = np.meshgrid(np.linspace(80, 430, 4), np.linspace(80, 430, 4))
    cx, cy = (v.ravel() + rng.uniform(-3, 3, 16) for v in grid)
    vectors = smear.smear_vectors(cx, cy)
    assert np.median(np.hypot(*vectors.T)) > 20.0
    steps = 120
    fractions = (np.arange(steps) + 0.5) / steps - 0.5
    x = (cx[:, None] + fractions[None] * vectors[:, 0:1]).ravel()
    y = (cy[:, None] + fractions[None] * vectors[:, 1:2]).ravel()
    frame = render(StarField.build(GaussianPsf(sigma_px), x, y), 40000.0 / steps, Detector(), SIZE, SIZE, rng)
    spots = extract_spots(frame.image, CentroidConfig())
    assert spots.psf.estimated and spots.psf.applied_sigma_px == pytest.approx(sigma_px, rel=0.08), spots.psf
    offsets = [float(np.min(np.hypot(spots.x - a, spots.y - b))) for a, b in zip(cx, cy)]
    assert max(offsets) < 0.3, offsets


def test_cosmic_ray_tracks_beside_round_stars_are_not_measured_as_streaks(database):
    # A frame at rest under 2000 rays /cm^2/s (the simulator): its elongated spots are tracks,
    # sharp across; measured as the frame's streaks they read as a 0.37 px PSF of 1 px stars.
    from star_tracker.models.attitude import radec_roll_to_matrix
    from star_tracker.models.catalog import load_hipparcos
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import StarFieldRenderer
    from star_tracker.sim.sensor import SensorModel

    camera = CameraModel.from_fov(1024, 1024, math.radians(15.0))
    catalog = load_hipparcos().at_epoch(database.config.epoch_jyear)
    sensor = SensorModel(exposure_s=0.1, cosmic_ray_rate_per_cm2_s=2000.0)
    renderer = StarFieldRenderer(camera, sensor, catalog, magnitude_limit=7.5)
    start = radec_roll_to_matrix(math.radians(80.0), math.radians(20.0), 0.0)
    frame = renderer.render(ConstantRateMotion(start, body_rate=np.zeros(3)), stamp_s=1.0, seed=frame_seed(7, 5))
    spots = extract_spots(frame.image, CentroidConfig())
    applied = spots.psf.applied_sigma_px if spots.psf.estimated else spots.psf.sigma_px
    assert applied == pytest.approx(sensor.psf_sigma_px, rel=0.1), spots.psf


def test_a_wide_psf_under_a_known_rate_is_measured_at_its_own_width_cold(database):
    from star_tracker.campaign.presets.default_chain import MAGNITUDE_LIMIT
    from star_tracker.models.attitude import quaternion_to_matrix
    from star_tracker.models.catalog import load_hipparcos
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import KIND_STAR, StarFieldRenderer
    from star_tracker.sim.sensor import SensorModel

    camera = CameraModel.from_fov(1024, 1024, math.radians(15.0))
    catalog = load_hipparcos().at_epoch(database.config.epoch_jyear)
    renderer = StarFieldRenderer(camera, replace(SensorModel(), psf_sigma_px=2.5), catalog,
                                 magnitude_limit=MAGNITUDE_LIMIT)
    axis = np.array([0.6, 0.8, 0.1]) / np.linalg.norm([0.6, 0.8, 0.1])
    motion = ConstantRateMotion(quaternion_to_matrix(np.array([0.3, -0.2, 0.5, 0.79])), axis * math.radians(1.0))
    frame = renderer.render(motion, 0.0, 17)
    spots = extract_spots(frame.image, CentroidConfig(), SmearModel(camera, motion.angular_velocity_at(0.0), 0.1))
    assert spots.psf.estimated and spots.psf.sigma_px == pytest.approx(2.5, rel=0.08)
    truth = frame.truth
    stars = truth.kind == KIND_STAR
    tx, ty = truth.x[stars], truth.y[stars]
    mahalanobis = []
    for i in range(len(spots)):
        nearest = int(np.argmin(np.hypot(tx - spots.x[i], ty - spots.y[i])))
        error = np.array([spots.x[i] - tx[nearest], spots.y[i] - ty[nearest]])
        if np.hypot(*error) < 3.0:
            mahalanobis.append(float(error @ np.linalg.solve(spots.cov[i], error)))
    # A consistent covariance gives a median of chi^2_2's, 1.39; measured at 1 px it was ~50.
    assert len(mahalanobis) > 50 and np.median(mahalanobis) < 2.5
