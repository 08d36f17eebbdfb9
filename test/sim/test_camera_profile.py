# SPDX-License-Identifier: Apache-2.0
"""
The camera-profile fit (star_tracker.sim.camera_profile).

It recovers a known camera from frames our simulator rendered with known values, it
reproduces the shipped profile of the real openstartracker frames, and the shipped profile
loads through the camera_simulator's parameter path (the CLI's --camera loader and the
node's declarations).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from star_tracker.models.attitude import radec_roll_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.parameter_spec import dotted_names
from star_tracker.sim.camera_profile import ProfileFrame, censored_gaussian_fit, fit_camera_profile
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel

REPO = Path(__file__).resolve().parents[2]
PROFILE = REPO / "config" / "camera_openstartracker.yaml"


def within(measured, truth, sigmas=3.0):
    return abs(measured.value - truth) <= sigmas * measured.sigma


def test_censored_gaussian_fit_recovers_clipped_rounded_noise():
    rng = np.random.default_rng(4)
    for mu, s in ((0.3, 4.0), (-1.0, 2.5), (20.0, 3.0)):
        values = np.clip(np.rint(rng.normal(mu, s, 50_000)), 0, None)
        fit_mu, fit_s, sigma_mu, sigma_s = censored_gaussian_fit(values)
        assert abs(fit_mu - mu) < 4 * sigma_mu and abs(fit_s - s) < 4 * sigma_s, (mu, s, fit_mu, fit_s)
        assert sigma_mu < 0.1 and sigma_s < 0.1
    # the naive statistics of the clipped values are far off: the censoring matters
    values = np.clip(np.rint(rng.normal(0.3, 4.0, 50_000)), 0, None)
    assert abs(values.mean() - 0.3) > 1.0


# A camera like the real one (8-bit, bias 0, black level at the sky), with known values.
TRUTH = SensorModel(exposure_s=0.05, psf_sigma_px=0.9, gain_e_per_adu=2.0, read_noise_e=6.0, bias_adu=0.0,
                    adc_bits=8, full_well_e=2000.0, background_e_per_px_s=40.0, vignetting_at_corner=0.3,
                    photon_flux_hp0=6.0e10, dark_e_per_px_s=0.0, dsnu_fraction=0.0, prnu_fraction=0.0,
                    hot_pixel_fraction=0.0, cosmic_ray_rate_per_cm2_s=0.0)


@pytest.mark.slow
def test_fit_recovers_known_camera_from_simulated_frames(catalog):
    camera = CameraModel.from_fov(1024, 768, math.radians(8.0))
    stars = catalog.at_epoch(2026.0).brighter_than(9.5)
    renderer = StarFieldRenderer(camera, TRUTH, stars, magnitude_limit=9.5)
    frames = []
    pointings = [(83.0, -2.0), (100.0, 5.0), (280.0, 35.0), (270.0, -25.0), (60.0, 20.0), (300.0, 40.0)]
    for k, (ra, dec) in enumerate(pointings):
        rotation = radec_roll_to_matrix(math.radians(ra), math.radians(dec), 0.4 * k)
        image = renderer.render(ConstantRateMotion(rotation, np.zeros(3)), 0.0, frame_seed(11, k)).image
        frames.append(ProfileFrame(image, camera, rotation, TRUTH.exposure_s))
    profile = fit_camera_profile(frames, stars, psf_sigma_guess_px=1.0)
    assert profile.used.sum() >= 30
    g = TRUTH.gain_e_per_adu
    background_adu = TRUTH.background_e_per_px_s * TRUTH.exposure_s / g
    zero_point = math.log10(TRUTH.zero_point_e_per_s / g)  # ADU/s
    assert within(profile.psf_sigma_px, TRUTH.psf_sigma_px) and profile.psf_sigma_px.sigma < 0.05
    assert abs(profile.psf_wing_excess.value) < 3 * profile.psf_wing_excess.sigma + 0.02  # Gaussian: no wings
    assert not profile.gain_is_lower_limit  # shot noise is seen
    assert within(profile.gain_e_per_adu, g) and profile.gain_e_per_adu.sigma < 0.2 * g
    expected_noise = math.sqrt((TRUTH.read_noise_e / g) ** 2 + background_adu / g + 1 / 12)  # + rounding
    assert abs(profile.background_noise_adu.value - expected_noise) < 0.05 * expected_noise
    assert within(profile.read_noise_e, TRUTH.read_noise_e)
    # the sky is vignetted: its level at the centre is the unvignetted one
    assert abs(profile.background_adu.value - background_adu) < 0.1
    assert within(profile.log10_zero_point_adu_per_s, zero_point) and profile.log10_zero_point_adu_per_s.sigma < 0.05
    assert within(profile.vignetting_at_corner, TRUTH.vignetting_at_corner)
    assert abs(profile.zero_point_free_slope.value + 0.4) < 0.015  # faint end selected bright, bright end by saturation
    # and the profile's sensor renders the same camera back
    sensor = profile.sensor_model()
    assert sensor.adc_bits == 8 and sensor.bias_adu == 0.0
    relative = 3 * math.hypot(math.log(10) * profile.log10_zero_point_adu_per_s.sigma, profile.gain_e_per_adu.sigma / g)
    assert abs(sensor.zero_point_e_per_s / TRUTH.zero_point_e_per_s - 1) < relative


def test_shipped_profile_loads_through_the_camera_simulator_parameters():
    from star_tracker.commands.camera_files import load_camera_file
    from star_tracker.ros.camera_simulator_parameters import declare_camera, declare_sensor

    loaded = load_camera_file(PROFILE)  # the CLI's --camera path
    assert (loaded.camera.width, loaded.camera.height) == (1392, 1040)
    pixel_scale_arcsec = math.degrees(loaded.camera.pixel_scale_rad) * 3600
    assert 15.6 < pixel_scale_arcsec < 15.8  # the set's astrometry.net scale (15.72"/px)
    assert loaded.sensor.adc_bits == 8 and loaded.sensor.bias_adu == 0.0 and loaded.sensor.exposure_s == 0.05
    # The node declares every parameter with its range: the file's values must all be inside.
    values = dotted_names(yaml.safe_load(PROFILE.read_text())["/**/camera_simulator"]["ros__parameters"])
    used = set()

    def declare(name, default, description, low=None, high=None):
        used.add(name)
        value = values.get(name, default)
        if low is not None:
            assert low <= value <= high, f"{name}={value} outside the node's range [{low}, {high}]"
        return value

    camera, _ = declare_camera(declare)
    sensor = declare_sensor(declare)
    assert camera == loaded.camera
    assert sensor == loaded.sensor  # the node and the CLI build the same sensor from the file
    assert set(values) <= used, f"keys the node does not declare: {sorted(set(values) - used)}"


@pytest.mark.slow
def test_real_set_fit_is_consistent_with_the_shipped_profile():
    from bench.corpus import CorpusMissing, find_corpus
    from bench.simulator_vs_real import catalog, load_real_frames
    from star_tracker.commands.camera_files import load_camera_file

    try:
        corpus = find_corpus()
    except CorpusMissing:
        pytest.skip("the real-image corpus (shared/realdata) is not beside the repository")
    real = load_real_frames(corpus)
    profile = fit_camera_profile([r.frame for r in real], catalog())
    shipped = load_camera_file(PROFILE).sensor
    assert profile.used.sum() >= 15  # well-measured real stars identified at their reference attitudes
    assert within(profile.psf_sigma_px, shipped.psf_sigma_px, 1.0)
    # the shipped gain is 1/slope, or the 2-sigma lower limit when shot noise is not seen
    assert within(profile.inverse_gain_adu_per_e, 1.0 / shipped.gain_e_per_adu, 2.5)
    g = shipped.gain_e_per_adu
    background_e = shipped.background_e_per_px_s * shipped.exposure_s
    shipped_noise_adu = math.sqrt((shipped.read_noise_e / g) ** 2 + background_e / g + 1 / 12)
    assert within(profile.background_noise_adu, shipped_noise_adu, 1.0)
    assert within(profile.vignetting_at_corner, shipped.vignetting_at_corner, 1.0)
    assert within(profile.log10_zero_point_adu_per_s, math.log10(shipped.zero_point_e_per_s / g), 1.0)
    # the real frames' photometry follows Hp: the fitted zero point scatters < 0.5 mag per star
    flux, hp = profile.stars.flux[profile.used], profile.stars.hp[profile.used]
    scatter_mag = np.std(-2.5 * (np.log10(flux) + 0.4 * hp))
    assert scatter_mag < 0.5
