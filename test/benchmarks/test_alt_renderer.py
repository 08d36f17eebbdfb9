# SPDX-License-Identifier: Apache-2.0
"""
The second renderer (bench/alt_renderer.py) knows its own truth.

Each PSF holds the star's flux, a noiseless star's centre of light is its truth position, its
noise has the stated variance, and its Cramér–Rao bound scales as 1/sqrt(flux) for bright
stars.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import alt_renderer as alt  # noqa: E402

# Well sampled PSFs (sigma >= ~0.8 px): the centre of light of the pixelated star is its centre
# (for narrower ones it is not -- the pixel-phase bias the centroider has to undo).
PSFS = {
    "gaussian": alt.GaussianPsf(1.0),
    "moffat": alt.MoffatPsf(2.5, beta=3.0, wing_fraction=1e-5),
    "annulus": alt.AnnulusPsf.with_equivalent_sigma(2.0),
    "elliptical": alt.EllipticalGaussianPsf(1.6, 0.9, np.radians(30.0)),
}
NOISELESS = alt.Detector(sky_e=0.0, read_noise_e=0.0)


@pytest.mark.parametrize("name", PSFS)
def test_noiseless_star_holds_its_flux_and_its_centre_of_light_is_the_truth(name):
    psf, rng = PSFS[name], np.random.default_rng(7)
    rows, cols = np.mgrid[0:128, 0:128]
    for xk, yk in zip(63.0 + rng.uniform(-0.5, 0.5, 5), 64.0 + rng.uniform(-0.5, 0.5, 5)):
        field = alt.StarField.build(psf, [xk], [yk])
        light = alt.star_signal(field, 1000.0, 128, 128)
        # All of the light but the Moffat's truncated wing (wing_fraction) is on the chip.
        assert light.sum() == pytest.approx(1000.0, rel=max(1.1 * getattr(psf, "wing_fraction", 0.0), 1e-6))
        assert light.sum() == pytest.approx(1000.0 * field.deposited_fractions(128, 128)[0], rel=1e-12)
        assert abs((light * cols).sum() / light.sum() - xk) < 1e-3
        assert abs((light * rows).sum() / light.sum() - yk) < 1e-3


def test_annulus_is_a_ring_and_its_second_moment_is_the_equivalent_sigma():
    psf = alt.AnnulusPsf.with_equivalent_sigma(3.0)
    centre, on_ring = psf.density(np.array(0.0), np.array(0.0)), psf.density(np.array(0.75 * psf.outer_radius_px),
                                                                             np.array(0.0))
    assert on_ring > 3 * centre  # dark centre: a defocused pupil's obstruction
    stamp = alt.star_stamp(psf, 30.3, 30.7)
    rows, cols = np.mgrid[stamp.row0:stamp.row0 + stamp.fractions.shape[0],
                          stamp.col0:stamp.col0 + stamp.fractions.shape[1]]
    second_moment = (stamp.fractions * (cols - 30.3) ** 2).sum()  # the pixels add 1/12
    assert second_moment == pytest.approx(3.0 ** 2 + 1.0 / 12.0, rel=1e-3)


def test_noise_has_the_stated_mean_and_variance_in_adu():
    detector = alt.Detector(sky_e=100.0, read_noise_e=6.0, gain_e_per_adu=2.0, bias_adu=200.0)
    nobody = alt.StarField.build(alt.GaussianPsf(1.0), np.zeros(0), np.zeros(0))
    image = alt.render(nobody, 0.0, detector, 256, 256, np.random.default_rng(3)).image.astype(float)
    assert image.mean() == pytest.approx(200.0 + 100.0 / 2.0, abs=0.05)
    assert image.var() == pytest.approx(detector.pixel_variance_e2 / 2.0 ** 2, rel=0.03)


def test_defects_and_clipping_are_where_the_truth_says():
    detector = alt.Detector(sky_e=10.0, read_noise_e=2.0, hot_pixel_fraction=2e-3, hot_pixel_e=(5000.0, 10000.0),
                            cosmic_rays_per_frame=4.0, adc_bits=12)
    nobody = alt.StarField.build(alt.GaussianPsf(1.0), np.zeros(0), np.zeros(0))
    first = alt.render(nobody, 0.0, detector, 200, 150, np.random.default_rng(1))
    second = alt.render(nobody, 0.0, detector, 200, 150, np.random.default_rng(2))
    hot = ~first.truth.defect_is_cosmic_ray
    cols, rows = first.truth.defect_x[hot].astype(int), first.truth.defect_y[hot].astype(int)
    assert hot.sum() == 60 and np.array_equal(first.truth.defect_x[hot],
                                              second.truth.defect_x[~second.truth.defect_is_cosmic_ray])
    assert np.all(first.image[rows, cols] >= 4095)  # 12-bit ADC: > 4000 e- at 1 e-/ADU clips
    assert first.image.max() == 4095
    rays = first.truth.defect_is_cosmic_ray
    for x, y, length in zip(first.truth.defect_x[rays], first.truth.defect_y[rays], first.truth.defect_extent_px[rays]):
        r, c = int(round(y)), int(round(x))
        window = first.image[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2]
        assert window.max() > 100 + 10 + 10 * 4  # the track's middle is lit


def test_cramer_rao_scales_as_one_over_sqrt_flux_for_bright_stars_and_matches_the_gaussian_limit():
    detector = alt.Detector(sky_e=40.0, read_noise_e=5.0)
    field = alt.StarField.build(alt.GaussianPsf(2.0), np.array([50.2]), np.array([50.7]))
    bright, brighter = alt.cramer_rao(field, 1e8, detector)[0], alt.cramer_rao(field, 4e8, detector)[0]
    assert np.sqrt(np.trace(brighter)) == pytest.approx(0.5 * np.sqrt(np.trace(bright)), rel=0.01)
    # Photon-limited, well sampled: var(x) -> (sigma^2 + 1/12) / F.
    assert bright[0, 0] == pytest.approx((4.0 + 1.0 / 12.0) / 1e8, rel=0.02)
    faint = alt.cramer_rao(field, 300.0, detector)[0]
    assert faint[0, 0] > 3 * (4.0 + 1.0 / 12.0) / 300.0  # background dominates faint stars


def test_optimal_snr_is_the_photon_limit_for_bright_stars():
    detector = alt.Detector(sky_e=40.0, read_noise_e=5.0)
    field = alt.StarField.build(alt.MoffatPsf(3.0), np.array([50.0]), np.array([50.0]))
    assert alt.optimal_snr(field, 1e8, detector)[0] == pytest.approx(np.sqrt(1e8), rel=0.01)


def test_stars_are_isolated_and_inside_the_margin():
    x, y = alt.place_stars(512, 512, 50, 30.0, 12.0, np.random.default_rng(0))
    assert x.size == 50 and x.min() >= 12.0 and y.max() <= 511 - 12.0
    d = np.hypot(x[:, None] - x[None], y[:, None] - y[None]) + np.eye(50) * 1e9
    assert d.min() >= 30.0
