# SPDX-License-Identifier: Apache-2.0
"""
The centroider's PSF estimate (centroid/psf/estimate.py) and the automatic PSF mode.

Tested on our simulator AND on frames from a renderer written here, independently of it
(pixel-integrated Gaussian by erf, a Moffat, a defocused annulus; Poisson + read noise; own
hot pixels and cosmic-ray tracks), and on a real image when the corpus is present.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.special import erf

from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid.psf.estimate import PsfEstimate

READ_NOISE_E = 5.0
SKY_E = 50.0  # background per pixel [e-]
BIAS_ADU = 100
SIZE = 512
SPACING = 64  # grid of isolated stars [px]


# ---------------------------------------------------------------- a renderer of our own (not sim/)

def _gaussian_stamp(dx: np.ndarray, dy: np.ndarray, sigma: float) -> np.ndarray:
    """
    Fraction of a Gaussian (sigma [px]) centred at offset (dx, dy) in each pixel of the stamp.

    The exact pixel integral, 1-D erf differences multiplied.
    """
    def axis(d):
        k = np.arange(-HALF, HALF + 1)[None, :] - d[:, None]
        return 0.5 * (erf((k + 0.5) / (np.sqrt(2) * sigma)) - erf((k - 0.5) / (np.sqrt(2) * sigma)))
    return axis(dy)[:, :, None] * axis(dx)[:, None, :]


def _sampled_stamp(dx, dy, profile, sub: int = 9) -> np.ndarray:
    """Pixel integral of a radial profile(r) by sub x sub samples per pixel, normalised to 1."""
    k = np.arange(-HALF, HALF + 1)
    offsets = (np.arange(sub) + 0.5) / sub - 0.5
    fine = (k[:, None] + offsets[None, :]).ravel()
    out = []
    for x0, y0 in zip(dx, dy):
        r = np.hypot(fine[None, :] - x0, fine[:, None] - y0)
        value = profile(r).reshape(k.size, sub, k.size, sub).sum(axis=(1, 3))
        out.append(value / value.sum())
    return np.array(out)


HALF = 18  # stamp half size [px]


def moffat(fwhm: float, beta: float = 3.0):
    alpha = fwhm / (2.0 * np.sqrt(2.0 ** (1.0 / beta) - 1.0))
    return lambda r: (1.0 + (r / alpha) ** 2) ** -beta


def annulus(radius: float, width: float = 1.0):
    """Return a defocused star: a ring of the given radius [px] and Gaussian cross-section 1-sigma width/2."""
    return lambda r: np.exp(-0.5 * ((r - radius) / (0.5 * width)) ** 2)


def render(psf, snr_range=(10.0, 300.0), seed: int = 0, hot_pixels: int = 0, cosmic_rays: int = 0):
    """
    One SIZE^2 uint16 frame [ADU, gain 1] of stars on a jittered SPACING grid.

    Fluxes set so that their SNR spans snr_range (log-uniform), sky SKY_E e-, Poisson +
    READ_NOISE_E read noise. psf: a Gaussian sigma [px] (float) or a radial profile function.
    Returns the image, the stars' (x, y) [px] and SNR, and the hot pixels' and cosmic rays'
    pixels (x, y).
    """
    rng = np.random.default_rng(seed)
    centres = np.arange(SPACING // 2, SIZE - SPACING // 2 + 1, SPACING, dtype=float)
    gx, gy = np.meshgrid(centres, centres)
    x = gx.ravel() + rng.uniform(-8, 8, gx.size)
    y = gy.ravel() + rng.uniform(-8, 8, gx.size)
    snr = np.exp(rng.uniform(*np.log(snr_range), x.size))
    ix, iy = np.rint(x).astype(int), np.rint(y).astype(int)
    if callable(psf):
        stamps = _sampled_stamp(x - ix, y - iy, psf)
    else:
        stamps = _gaussian_stamp(x - ix, y - iy, psf)
    # Effective pixels of the PSF: 1 / sum(p^2) (4 pi sigma^2 for a Gaussian); SNR -> flux.
    n_eff = 1.0 / np.sum(stamps ** 2, axis=(1, 2))
    noise2 = n_eff * (SKY_E + READ_NOISE_E ** 2)
    flux = 0.5 * (snr ** 2 + np.sqrt(snr ** 4 + 4 * snr ** 2 * noise2))
    light = np.full((SIZE, SIZE), SKY_E)
    for k in range(x.size):
        light[iy[k] - HALF:iy[k] + HALF + 1, ix[k] - HALF:ix[k] + HALF + 1] += flux[k] * stamps[k]
    electrons = rng.poisson(light) + rng.normal(0.0, READ_NOISE_E, light.shape)
    defects = []
    for _ in range(hot_pixels):  # between the stars
        px, py = rng.integers(0, SIZE // SPACING, 2) * SPACING + rng.integers(-3, 4, 2)
        electrons[py, px] += rng.uniform(300, 20000)
        defects.append((px, py))
    for _ in range(cosmic_rays):  # straight tracks a pixel wide, 3-15 px long
        px, py = rng.integers(0, SIZE // SPACING, 2) * SPACING + 4
        angle, length = rng.uniform(0, np.pi), rng.integers(3, 16)
        for t in range(length):
            cx, cy = int(px + t * np.cos(angle)), int(py + t * np.sin(angle))
            if 0 <= cx < SIZE and 0 <= cy < SIZE:
                electrons[cy, cx] += rng.uniform(500, 3000)
                defects.append((cx, cy))
    image = np.clip(np.rint(electrons + BIAS_ADU), 0, 65535).astype(np.uint16)
    return image, np.column_stack([x, y]), snr, np.array(defects, float).reshape(-1, 2)


def _found(spots, xy, reach: float) -> np.ndarray:
    if len(spots) == 0:
        return np.zeros(len(xy), bool)
    d = np.hypot(xy[:, 0, None] - spots.x[None], xy[:, 1, None] - spots.y[None])
    return d.min(axis=1) < reach


def _false(spots, xy, reach: float) -> int:
    if len(spots) == 0:
        return 0
    d = np.hypot(spots.x[:, None] - xy[None, :, 0], spots.y[:, None] - xy[None, :, 1])
    return int(np.sum(d.min(axis=1) >= reach))


CONFIG = CentroidConfig(saturation_adu=60000.0)


# ---------------------------------------------------------------- foreign frames

@pytest.mark.parametrize("sigma", [0.35, 0.45, 0.6, 1.0, 2.0, 3.0])
def test_estimate_and_detection_on_foreign_gaussian_frames(sigma):
    """
    Pixel-integrated Gaussians of our own renderer.

    The estimate is within 5 % of the true sigma and >= 99 % of the SNR >= 10 stars are found
    with the default config.
    """
    found, estimates = [], []
    for seed in range(2):
        image, xy, snr, _ = render(sigma, seed=seed)
        spots = extract_spots(image, CONFIG)
        assert spots.psf.source == "estimated", spots.psf.reason
        estimates.append(spots.psf.sigma_px)
        found.append(_found(spots, xy, 2.0 + sigma))
        assert _false(spots, xy, 2.0 + 2 * sigma) <= 1
    assert np.allclose(estimates, sigma, rtol=0.05), estimates
    assert np.mean(np.concatenate(found)) >= 0.99


# Moffat beta 3, FWHM 2.5 px: alpha = FWHM / (2 sqrt(2^(1/3) - 1)); its core's Gaussian is FWHM / 2.355,
# its second moment per axis alpha^2 / (2 (beta - 2)) (the wings'): an equivalent Gaussian lies between.
_ALPHA = 2.5 / (2.0 * np.sqrt(2.0 ** (1.0 / 3.0) - 1.0))


@pytest.mark.parametrize("name, profile, between, complete_from", [
    ("moffat beta 3", moffat(2.5), (2.5 / 2.3548, _ALPHA / np.sqrt(2.0)), 10.0),
    ("defocused annulus", annulus(2.5), (1.0, 2.5), 15.0),
])
def test_non_gaussian_psfs_keep_their_stars(name, profile, between, complete_from):
    """
    A broad-wing Moffat (FWHM 2.5 px) and a defocused annulus (radius 2.5 px).

    The estimate is an equivalent Gaussian (the Moffat's between its core's and its second
    moment's widths, the annulus' between 0.4x and 1x its radius); every star from SNR
    complete_from (the Moffat's 10; the ring's 15: a Gaussian-matched filter and aperture lose
    a ring's faintest) and >= 95 % of the SNR >= 10 ones are found, the bright ones (SNR >=
    50) within 0.15 px (the ring's: 70 % of them, median < 0.1 px: the blend splitter takes
    some bright rings' two sides for two stars, a known limit).
    """
    image, xy, snr, _ = render(profile, seed=3)
    spots = extract_spots(image, CONFIG)
    assert spots.psf.source == "estimated", spots.psf.reason
    assert between[0] <= spots.psf.sigma_px <= between[1]
    found = _found(spots, xy, 3.0)
    assert found.mean() >= 0.95
    assert found[snr >= complete_from].all()
    d = np.hypot(xy[:, 0, None] - spots.x[None], xy[:, 1, None] - spots.y[None])
    error = d.min(axis=1)[snr >= 50]
    assert np.mean(error < 0.15) >= (1.0 if name.startswith("moffat") else 0.7)
    assert np.median(error) < 0.1


def test_own_hot_pixels_and_cosmic_rays_are_still_rejected_with_a_sharp_psf():
    """
    An undersampled PSF (sigma 0.45 px) looks most like a hot pixel.

    With the estimate, the shape test still rejects our own hot pixels and cosmic-ray tracks
    (<= 1 false detection), and the estimate is not pulled by them.
    """
    image, xy, snr, defects = render(0.45, seed=5, hot_pixels=30, cosmic_rays=10)
    spots = extract_spots(image, CONFIG)
    assert spots.psf.sigma_px == pytest.approx(0.45, rel=0.05)
    # 63 of 64 (one SNR-10 star whose noisy moments look like a short streak the streak fit
    # then drops, as at the fixed sigma 0.45).
    assert _found(spots, xy, 2.5).mean() >= 0.98
    assert _false(spots, xy, 3.0) <= 1


@pytest.mark.parametrize("sigma, words", [(0.15, ""), (7.0, "outside")])
def test_a_psf_outside_the_supported_range_falls_back_with_a_reason(sigma, words):
    """
    Far too sharp (0.15 px: no star can be told from a hot pixel) or too wide (7 px).

    No crash, the prior is used and the reason says why.
    """
    image, xy, _, _ = render(sigma, snr_range=(50.0, 300.0), seed=7)
    spots = extract_spots(image, CONFIG)
    assert spots.psf.source == "prior"
    assert spots.psf.sigma_px == CONFIG.psf_sigma_px
    assert spots.psf.reason and words in spots.psf.reason


def test_noise_only_frame_gives_the_reason():
    rng = np.random.default_rng(1)
    image = np.clip(rng.normal(200, 5, (256, 256)), 0, 65535).astype(np.uint16)
    spots = extract_spots(image, CONFIG)
    assert spots.psf.source == "prior" and spots.psf.reason


def test_fixed_mode_and_no_psf_are_configured():
    image, xy, _, _ = render(1.0, seed=2)
    fixed = extract_spots(image, CentroidConfig(saturation_adu=60000.0, psf_mode="fixed", psf_sigma_px=1.2))
    assert fixed.psf.source == "configured" and fixed.psf.sigma_px == 1.2
    cog = extract_spots(image, CentroidConfig(saturation_adu=60000.0, psf_sigma_px=0.0, method="cog"))
    assert cog.psf.source == "configured" and cog.psf.sigma_px == 0.0
    assert _found(cog, xy, 3.0).mean() >= 0.99


def test_a_prior_close_to_the_truth_is_kept_and_a_far_one_replaced():
    """
    Within the tolerance the frame is measured with the prior exactly (the estimate still reported).

    A round PSF's prior 6 % off, a difference its estimate resolves, is replaced (bright stars
    fitted too narrow or wide lean); one 2x off is too (psf_prior overrides the config).
    """
    image, xy, _, _ = render(1.0, seed=4)
    near = extract_spots(image, CONFIG, psf_prior=1.02)
    assert near.psf.applied_sigma_px == 1.02
    assert near.psf.sigma_px == pytest.approx(1.0, rel=0.05)
    off = extract_spots(image, CONFIG, psf_prior=1.06)
    assert off.psf.applied_sigma_px == off.psf.sigma_px == pytest.approx(1.0, rel=0.02)
    far = extract_spots(image, CONFIG, psf_prior=2.0)
    assert far.psf.applied_sigma_px == far.psf.sigma_px == pytest.approx(1.0, rel=0.05)


def test_an_elongated_psf_is_measured():
    """
    An astigmatic PSF (sigma 1.5 x 0.9 px, major axis at 30 deg) from our renderer.

    Axes within 10 %, angle within 10 deg.
    """
    major, minor, angle = 1.5, 0.9, np.radians(30.0)
    c, s = np.cos(angle), np.sin(angle)

    def profile_xy(dx, dy):
        u, v = c * dx + s * dy, -s * dx + c * dy
        return np.exp(-0.5 * ((u / major) ** 2 + (v / minor) ** 2))

    rng = np.random.default_rng(8)
    light = np.full((SIZE, SIZE), SKY_E)
    k = np.arange(-HALF, HALF + 1)
    offsets = (np.arange(9) + 0.5) / 9 - 0.5
    fine = (k[:, None] + offsets[None, :]).ravel()
    for cy in range(SPACING // 2, SIZE, SPACING):
        for cx in range(SPACING // 2, SIZE, SPACING):
            dx, dy = rng.uniform(-0.5, 0.5, 2)
            stamp = profile_xy(fine[None, :] - dx, fine[:, None] - dy).reshape(k.size, 9, k.size, 9).sum(axis=(1, 3))
            light[cy - HALF:cy + HALF + 1, cx - HALF:cx + HALF + 1] += 20000.0 * stamp / stamp.sum()
    image = np.clip(rng.poisson(light) + rng.normal(0, READ_NOISE_E, light.shape) + BIAS_ADU, 0, 65535)
    psf = extract_spots(image.astype(np.uint16), CONFIG).psf
    assert psf.source == "estimated"
    assert psf.sigma_major_px == pytest.approx(major, rel=0.10)
    assert psf.sigma_minor_px == pytest.approx(minor, rel=0.10)
    assert abs(np.degrees(psf.angle_rad) - 30.0) < 10.0
    assert psf.elongation == pytest.approx(major / minor, rel=0.1)


def test_psf_estimate_record_checks_its_source():
    with pytest.raises(ValueError, match="source"):
        PsfEstimate(1.0, 1.0, 1.0, 0.0, 0.01, 5, "guessed")


def test_running_psf_carries_the_median_and_resets_on_a_failed_estimate():
    from star_tracker.centroid.psf.running_prior import RunningPsf

    running = RunningPsf(frames=3)
    assert running.prior is None
    for sigma in (0.50, 0.52, 0.90, 0.51):
        running.update(PsfEstimate(sigma, sigma, sigma, 0.0, 0.01, 10, "estimated"))
    assert running.prior == pytest.approx(0.52)  # the median of the last 3: one outlier does not move it
    assert not running.rings
    for _ in range(2):
        running.update(PsfEstimate(2.0, 2.0, 2.0, 0.0, 0.01, 10, "estimated", annular=True))
    assert running.rings  # 2 of the last 3 frames' stars were rings
    running.update(PsfEstimate.assumed(1.0, "prior", "too few stars"))
    assert running.prior is None and not running.rings


def test_a_running_prior_of_rings_saves_a_defocused_frames_second_pass(monkeypatch):
    """
    Check that a ring-star frame measured from the last frame's width and ring shape needs one pass.

    Its spots are those of the cold two-pass measurement (the same width, blends split as rings).
    """
    from star_tracker.centroid import frame_measurement

    image, xy, snr, _ = render(annulus(2.5), seed=4)
    cold = extract_spots(image, CONFIG)
    assert cold.psf.annular, cold.psf
    passes = []
    measure = frame_measurement.measure_candidates
    monkeypatch.setattr(frame_measurement, "measure_candidates",
                        lambda *args, **kwargs: passes.append(kwargs.get("rings")) or measure(*args, **kwargs))
    warm = extract_spots(image, CONFIG, psf_prior=cold.psf.applied_sigma_px, prior_rings=True)
    assert passes == [True], passes
    assert warm.psf.applied_sigma_px == cold.psf.applied_sigma_px and warm.psf.annular
    assert np.array_equal(warm.x, cold.x) and np.array_equal(warm.y, cold.y)
    assert _found(warm, xy[snr >= 15.0], 1.0).mean() == 1.0  # the truth: every star of SNR >= 15
    passes.clear()
    extract_spots(image, CONFIG, psf_prior=cold.psf.applied_sigma_px)  # the width alone: measured twice
    assert passes == [False, True], passes


def test_the_running_prior_saves_the_second_pass():
    """
    Check that a frame measured from the last frame's estimate needs one pass.

    It gives the same spots as the two-pass measurement from a wrong prior.
    """
    image, xy, _, _ = render(0.5, seed=9)
    cold = extract_spots(image, CONFIG)
    warm = extract_spots(image, CONFIG, psf_prior=cold.psf.sigma_px)
    assert warm.psf.applied_sigma_px == cold.psf.applied_sigma_px
    assert np.array_equal(warm.x, cold.x) and np.array_equal(warm.y, cold.y)


# ---------------------------------------------------------------- our simulator

def _sim_frame(catalog, camera, sigma: float, seed: int, **sensor_values):
    from star_tracker.models.attitude import radec_roll_to_matrix
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import StarFieldRenderer, frame_seed
    from star_tracker.sim.sensor import SensorModel

    sensor = SensorModel(psf_sigma_px=sigma, **sensor_values)
    renderer = StarFieldRenderer(camera, sensor, catalog, magnitude_limit=7.5, fixed_pattern_seed=seed)
    frame = renderer.render(ConstantRateMotion(radec_roll_to_matrix(1.4, 0.35, 0.2), np.zeros(3)), 10.0,
                            frame_seed(3, seed))
    return frame, sensor


@pytest.mark.parametrize("sigma", [0.4, 0.6, 1.0, 2.0, 3.0])
def test_estimate_and_detection_on_our_simulator(catalog, nominal_camera, sigma):
    """
    Our renderer at PSF sigma 0.4-3 px.

    Estimate within 5 %, >= 99 % of the isolated SNR >= 10 stars found with the default
    config, over two noise realizations of the field (one frame's ~70 stars cannot tell 99 %
    from 98.6 %: a single star whose noise left it at SNR ~5).
    """
    found = []
    for seed in (1, 2):
        frame, sensor = _sim_frame(catalog, nominal_camera, sigma, seed=seed)
        spots = extract_spots(frame.image, CONFIG)
        assert spots.psf.source == "estimated", spots.psf.reason
        assert spots.psf.sigma_px == pytest.approx(sigma, rel=0.05)
        t = frame.truth
        width, height = nominal_camera.width, nominal_camera.height
        inside = t.stars() & (t.x > 10) & (t.x < width - 11) & (t.y > 10) & (t.y < height - 11)
        d = np.hypot(t.x[:, None] - t.x[None], t.y[:, None] - t.y[None])
        np.fill_diagonal(d, np.inf)
        alone = d.min(axis=1) > 8.0 * max(sigma, 1.0)  # (a pair 6.7 px apart is lost at sigma 1 with any mode)
        static = (sensor.background_e_per_px_s + sensor.dark_e_per_px_s_at_temperature) * sensor.exposure_s
        snr = t.electrons / np.sqrt(t.electrons + 4 * np.pi * sigma ** 2 * (static + sensor.read_noise_e ** 2))
        scored = inside & alone & (snr >= 10)
        assert scored.sum() >= 20
        found.append(_found(spots, np.column_stack([t.x[scored], t.y[scored]]), 2.0 + sigma))
    assert np.concatenate(found).mean() >= 0.99


def test_star_free_simulated_frames_with_hot_pixels_and_cosmic_rays(catalog, nominal_camera):
    """
    Our simulator's hot pixels and cosmic rays (4x the node defaults' rate), no stars.

    <= 1 false detection per frame, and no PSF estimated from the defects.
    """
    from star_tracker.models.catalog import StarCatalog

    empty = StarCatalog(*(np.zeros(0) for _ in range(7)))
    for seed in range(3):
        frame, _ = _sim_frame(empty, nominal_camera, 1.0, seed, hot_pixel_fraction=8e-5, cosmic_ray_rate_per_cm2_s=20.0,
                              dsnu_fraction=0.1, prnu_fraction=0.01)
        assert (frame.truth.kind != 0).sum() > 20  # the defects are there
        spots = extract_spots(frame.image, CONFIG)
        assert len(spots) <= 1
        assert spots.psf.source == "prior" and spots.psf.reason


# ---------------------------------------------------------------- a real image

REAL_IMAGE = "openstartracker_img2"  # 6.1 deg field, sharp stars: not solved at a fixed sigma of 1 px


@pytest.mark.slow
def test_real_image_psf_is_estimated_and_the_image_solves_at_defaults():
    """
    A real camera frame (openstartracker, sharp undersampled stars).

    The estimate is 0.4-0.7 px from the image itself, and `solve --fov` at the defaults now
    solves it within 1' of the manifest (astrometry.net) reference.
    """
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
    from bench import bench_realdata as bench
    from star_tracker.commands.images import read_image

    try:
        corpus = bench.find_corpus()
    except bench.CorpusMissing as exc:
        pytest.skip(f"real-image corpus absent: {exc}")
    (image,) = bench.load_corpus(corpus, [REAL_IMAGE])
    pixels = read_image(image.path).pixels
    psf = extract_spots(pixels, CentroidConfig(saturation_adu=255.0, max_spots=150)).psf
    assert psf.source == "estimated", psf.reason
    assert 0.4 <= psf.sigma_px <= 0.7
    result = bench.solve_ours(image, warm_up=False)
    assert result["solved"], result["status"]
    assert result["within_1arcmin"], f"boresight {np.degrees(result['boresight_error_rad']) * 60:.2f}'"


def test_faint_undersampled_stars_give_an_estimate_and_are_kept():
    """
    Stars of sigma 0.4 px at SNR ~11 (300 e-, our renderer with hot pixels and cosmic rays).

    Their noisy moments once made most of them look elongated (minor axis ~0 with the pixel
    term removed), the estimate fell back to the 1 px prior and the shape test dropped half of
    the stars as too sharp (49 % detected in docs/BENCHMARKS.md § Centroiding across PSFs).
    """
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
    from bench.scenes import CAMERA, POINTING, grid_scene
    from bench.bench_psf_range import simulator_sensor
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import KIND_STAR, StarFieldRenderer, frame_seed

    sensor = simulator_sensor(0.4)
    found = total = 0
    for k in range(3):
        scene = grid_scene(sensor, 300.0, np.random.default_rng([5, k]))
        frame = StarFieldRenderer(CAMERA, sensor, scene, magnitude_limit=30.0).render(
            ConstantRateMotion(POINTING, np.zeros(3)), 1.0, frame_seed(5, k))
        stars = frame.truth.kind == KIND_STAR
        tx, ty = frame.truth.x[stars], frame.truth.y[stars]
        spots = extract_spots(frame.image, CentroidConfig())
        assert spots.psf.source == "estimated", spots.psf.reason
        assert 0.3 <= spots.psf.sigma_px <= 0.5
        distance = np.hypot(spots.x[:, None] - tx[None], spots.y[:, None] - ty[None]).min(axis=0)
        found += int((distance < 1.8).sum())
        total += tx.size
    assert found >= 0.75 * total, f"{found} of {total} stars found"


@pytest.mark.parametrize("ring", [True, False], ids=["defocused_annulus", "gaussian"])
def test_ring_stars_are_told_and_not_split_as_blends(ring):
    """
    A defocused PSF (a ring, from bench/alt_renderer.py, not our renderer) at 30 000 e- per star.

    The estimate says annular (a Gaussian of the same width: not), and the ring's maxima are
    not split as two stars: one spot per star, the positions at ~2.5x the CRB (26x when the
    rings were split as blends; docs/BENCHMARKS.md § Centroiding across PSFs).
    """
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
    from bench import alt_renderer as alt
    from bench.bench_psf_range import ALT_DETECTOR, ALT_SIZE, ALT_STARS

    rng = np.random.default_rng(17)
    psf = alt.AnnulusPsf.with_equivalent_sigma(2.0, blur_fraction=0.3) if ring else alt.GaussianPsf(2.0)
    x, y = alt.place_stars(ALT_SIZE, ALT_SIZE, ALT_STARS, 12.0, 14.0, rng)
    frame = alt.render(alt.StarField.build(psf, x, y), 30000.0, ALT_DETECTOR, ALT_SIZE, ALT_SIZE, rng)
    spots = extract_spots(frame.image, CentroidConfig())
    assert spots.psf.source == "estimated" and spots.psf.annular == ring
    distance = np.hypot(spots.x[:, None] - x[None], spots.y[:, None] - y[None])
    nearest = distance.min(axis=1)
    assert np.sum(nearest < 5.0) <= x.size + 1  # no star split in two
    error = distance.min(axis=0)
    found = error < 5.0
    assert found.sum() >= x.size - 2
    assert np.sqrt(np.mean(error[found] ** 2)) < 0.08


def _bench_psf_range():
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
    from bench import bench_psf_range
    return bench_psf_range


def _alt_row(psf, flux_e: float, seed: int, fields: int = 4):
    """
    Score default-config spots on `fields` frames of bench/alt_renderer.py as bench_psf_range does.

    Not our renderer: its own noise, hot pixels and cosmic rays, 50 stars a frame; stars near a
    defect are not scored, a hit is within 2 sigma + 1 px (no CRB). Returns the row
    (Scored.row) and each frame's PsfEstimate.
    """
    bench = _bench_psf_range()
    score, estimates = bench.Scored(), []
    for k in range(fields):
        rng = np.random.default_rng([seed, k])
        frame = bench.alt.render(bench.alt_star_field(psf, rng), flux_e, bench.ALT_DETECTOR, bench.ALT_SIZE,
                                 bench.ALT_SIZE, rng)
        spots = extract_spots(frame.image, CentroidConfig())
        t = frame.truth
        score.add(spots, t.x, t.y, t.snr, np.full(t.x.size, np.nan), t.defect_x, t.defect_y, t.defect_extent_px,
                  psf.equivalent_sigma_px, 0.0)
        estimates.append(spots.psf)
    return score.row(), estimates


@pytest.mark.parametrize("psf_name", ["astigmatic", "sharp"])
def test_faint_astigmatic_and_sharp_stars_pass_the_shape_test(psf_name):
    """
    SNR ~22-26 stars (1000 e-) of an astigmatic PSF (sigma 1.30 x 0.77 px) and of a sharp one (sigma 0.6 px).

    The astigmatic stars' minor axis, ~0.6 x the 1 px prior's width, once failed the width
    test at the prior (96.4 % of these stars found); the sharp stars' wide detection
    footprints, stretched by their own noise past the point-like limit, once made them streaks
    that the cross-track test dropped (98.98 %). Now >= 99.5 % of them are found.
    """
    alt = _bench_psf_range().alt
    psf = alt.EllipticalGaussianPsf(1.3, 1.0 / 1.3, np.radians(30.0)) if psf_name == "astigmatic" \
        else alt.GaussianPsf(0.6)
    row, estimates = _alt_row(psf, 1000.0, seed=23)
    assert all(e.source == "estimated" for e in estimates), [e.reason for e in estimates]
    assert row["stars_snr_ge_10"] >= 150
    assert row["detected_snr_ge_10"] >= 0.995, row


def test_faint_defocused_stars_are_estimated_at_a_wider_prior():
    """
    Defocused stars (Gaussian sigma 3 px, 1000 e-: SNR ~11, every star this faint; bench/alt_renderer.py).

    Measured at the 1 px prior their footprint SNR is ~5 and their peaks ~2 noise sigmas:
    no star was usable for the estimate, the frame stayed at 1 px and 84.5 % of the stars were
    found (no frame estimated). Re-measured at 2x / 3x the prior, stars from footprint SNR 6 give the
    estimate: within 15 % of 3 px on >= 3 of 4 frames, >= 97 % of the stars found.
    """
    row, estimates = _alt_row(_bench_psf_range().alt.GaussianPsf(3.0), 1000.0, seed=29)
    assert sum(e.estimated and abs(e.sigma_px - 3.0) <= 0.45 for e in estimates) >= 3
    assert row["stars_snr_ge_10"] >= 150
    assert row["detected_snr_ge_10"] >= 0.97, row


@pytest.mark.parametrize("field", [2, 4])
def test_a_coarsely_quantised_frames_round_psf_is_measured_round(field):
    # bench_psf_range's 12-bit sensor at 16 e-/ADU (the alt renderer), 1,000 e- stars of a round
    # 1 px PSF: ~10 ADU peaks on a background whose median is off by up to half an ADU. Under the
    # weight (2 sigma) the windows' offset made the stars' weighted moments negative, the PSF
    # was read 3.8x (field 2) and 1.6x (field 4) elongated and measured across its "minor axis"
    # (0.52 and 0.65 px), the spots 2.6x and 1.6x their Cramer-Rao bound.
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
    from bench import alt_renderer as alt
    from bench.bench_psf_range import ALT_DETECTOR_12BIT, ALT_SIZE, FLUXES, alt_star_field

    rng = np.random.default_rng([1721, field])  # the bench's alt 12-bit case, its field `field`
    star_field = alt_star_field(alt.GaussianPsf(1.0), rng)
    for flux in FLUXES:  # the bench renders every flux in turn from the field's generator
        frame = alt.render(star_field, flux, ALT_DETECTOR_12BIT, ALT_SIZE, ALT_SIZE, rng)
        if flux == 1000.0:
            break
    spots = extract_spots(frame.image, CentroidConfig())
    assert spots.psf.estimated, spots.psf
    assert spots.psf.sigma_major_px / spots.psf.sigma_minor_px < 1.25, spots.psf
    assert spots.psf.applied_sigma_px == pytest.approx(1.0, rel=0.1), spots.psf
    t = frame.truth
    d = np.hypot(t.x[:, None] - spots.x[None], t.y[:, None] - spots.y[None])
    near = d.min(axis=1) < 3.0
    crb = alt.cramer_rao(star_field, 1000.0, ALT_DETECTOR_12BIT)
    assert near.sum() >= 45
    rms_ratio = np.sqrt(np.mean(d.min(axis=1)[near] ** 2) / np.mean((crb[:, 0, 0] + crb[:, 1, 1])[near]))
    assert rms_ratio < 1.3, rms_ratio
