# SPDX-License-Identifier: Apache-2.0
"""
PSFs with wings: the core/halo model (Gaussians on one centre) and the centroider on undersampled Moffat stars.

Frames from bench/alt_renderer.py (not our renderer: its Moffat PSF supersampled over each
pixel, its own noise, hot pixels and cosmic rays); errors judged against its truth and its
Cramer-Rao bound.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid.psf import single_star_model
from star_tracker.centroid.psf.core_halo import CoreHaloPsf, estimate_core_halo
from star_tracker.centroid.psf.empirical import fit_empirical
from star_tracker.centroid.windows import PsfStart, PsfWindows

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import alt_renderer as alt  # noqa: E402

from alt_scoring import DETECTOR, SIZE, rms_over_crb  # noqa: E402


def _windows(psf_sample, n: int, size: int, flux: float, rng):
    """Return n windows of one star each (random sub-pixel phase, 5 ADU noise): data, valid, col0, row0, x, y."""
    col0 = rng.integers(0, 200, n).astype(float)
    row0 = rng.integers(0, 200, n).astype(float)
    half = size // 2
    x = col0 + half + rng.uniform(-0.5, 0.5, n)
    y = row0 + half + rng.uniform(-0.5, 0.5, n)
    steps = np.arange(size, dtype=float)
    dx = (col0[:, None] + steps)[:, None, :] - x[:, None, None]
    dy = (row0[:, None] + steps)[:, :, None] - y[:, None, None]
    share = psf_sample(*np.broadcast_arrays(dx, dy))
    return flux * share + rng.normal(0.0, 5.0, share.shape), np.ones(share.shape, bool), col0, row0, x, y


def test_the_model_is_pixel_integrated_gaussians_on_one_centre():
    psf = CoreHaloPsf(0.45, (0.8, 1.7), (0.3, 0.1))
    dx, dy = np.meshgrid(np.arange(-5, 6) + 0.27, np.arange(-5, 6) - 0.41)
    value, grad_x, grad_y = psf.sample(dx, dy)
    truth = (0.6 * alt.GaussianPsf(0.45).pixel_fractions(dx, dy) + 0.3 * alt.GaussianPsf(0.8).pixel_fractions(dx, dy)
             + 0.1 * alt.GaussianPsf(1.7).pixel_fractions(dx, dy))
    assert np.max(np.abs(value - truth)) < 1e-9
    step = 1e-6
    assert np.allclose((psf.sample(dx + step, dy)[0] - value) / step, grad_x, atol=1e-5)
    assert np.allclose((psf.sample(dx, dy + step)[0] - value) / step, grad_y, atol=1e-5)
    shares = psf.window_shares(np.array([10.0]), np.array([20.0]), np.array([15.3]), np.array([24.8]), 11)[0]
    steps = np.arange(11, dtype=float)
    expected, _, _ = psf.sample(*np.meshgrid(10 + steps - 15.3, 20 + steps - 24.8))
    assert np.allclose(shares, expected, atol=1e-12)


def test_the_compiled_fit_is_the_reference_gauss_newton():
    rng = np.random.default_rng(5)
    psf = CoreHaloPsf(0.5, (0.9, 1.8), (0.25, 0.1))
    data, valid, col0, row0, x, y = _windows(lambda a, b: psf.sample(a, b)[0], 30, 9, 4000.0, rng)
    valid &= rng.random(valid.shape) > 0.03
    start = (x + 0.3, y - 0.2, np.full(x.size, 3000.0))
    compiled = psf.fit(PsfWindows(data, valid, col0, row0), PsfStart(*start), 5.0, 1.0)
    reference = fit_empirical(psf, PsfWindows(data, valid, col0, row0), PsfStart(*start), 5.0, 1.0, iterations=12)
    assert compiled.converged.all() and reference[5].all()
    assert np.max(np.abs(compiled.x[:, 0] - reference[0])) < 1e-4
    assert np.max(np.abs(compiled.y[:, 0] - reference[1])) < 1e-4
    scale = compiled.cov[:, 0, 0, 0][:, None, None]
    # Each reports the information at its last iterate (the two stop at different steps).
    assert np.all(np.abs(compiled.cov[:, 0] - reference[3]) < 5e-3 * scale)


def test_the_shape_is_found_from_stars_of_that_shape():
    rng = np.random.default_rng(8)
    truth = CoreHaloPsf(0.55, (1.0, 2.0), (0.3, 0.1))
    data, valid, col0, row0, x, y = _windows(lambda a, b: truth.sample(a, b)[0], 30, 11, 20000.0, rng)
    # Started from biased positions (a one-Gaussian fit's) and the one-Gaussian width.
    found = estimate_core_halo(PsfWindows(data, valid, col0, row0), x + rng.normal(0, 0.02, x.size),
                               y + rng.normal(0, 0.02, y.size), 0.8, 5.0, 1.0)
    assert found is not None
    # Judged on what the centre depends on: the profile, within 1 % of its peak.
    dx, dy = np.meshgrid(np.arange(-5, 6) + 0.3, np.arange(-5, 6) - 0.2)
    expected = truth.sample(dx, dy)[0]
    assert np.max(np.abs(found.sample(dx, dy)[0] - expected)) < 0.01 * expected.max()
    assert abs(found.core_px - 0.55) < 0.05


def test_a_gaussian_frame_keeps_the_gaussian(monkeypatch):
    chosen = []
    original = single_star_model.fit_frame_model

    def recording(*args):
        model, fit = original(*args)
        chosen.append(model)
        return model, fit

    monkeypatch.setattr("star_tracker.centroid.psf.point_fits.fit_frame_model", recording)
    for seed in range(3):
        rng = np.random.default_rng([23, seed])
        x, y = alt.place_stars(SIZE, SIZE, 50, 12.0, 12.0, rng)
        frame = alt.render(alt.StarField.build(alt.GaussianPsf(0.6), x, y), 30000.0, DETECTOR, SIZE, SIZE, rng)
        assert extract_spots(frame.image, CentroidConfig()).fit_model == "gaussian"
    assert chosen and all(model is None for model in chosen)


@pytest.mark.parametrize("flux", [5000.0, 30000.0])
def test_undersampled_stars_with_wings_are_centred_near_the_cramer_rao_bound(flux):
    # Moffat beta 3 of FWHM 0.94 px (equivalent sigma 0.4 px), SNR ~65 and ~170, the width
    # unknown to the centroider: one Gaussian read 1.74x the bound at 5000 e- on these frames
    # (its centre pulled with the sub-pixel phase); a core and one halo Gaussian 1.09x at
    # 5000 e- and 1.30x at 30000 e- (bench_psf_range), where its misfit outgrows the noise.
    def with_wings(spots):
        assert spots.fit_model == "core_halo"

    ratio, found, scored = rms_over_crb(alt.MoffatPsf(0.4 / alt.SIGMA_PER_FWHM, beta=3.0), flux,
                                        [[0, seed] for seed in range(4)], clear_px=5.0, check=with_wings)
    assert found >= 0.99 * scored
    print(f"RMS / CRB {ratio:.3f}")
    assert ratio < 1.2, ratio
