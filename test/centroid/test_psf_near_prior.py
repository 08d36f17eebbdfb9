# SPDX-License-Identifier: Apache-2.0
"""
A PSF a few per cent wider or narrower than the prior is fitted at its own width.

Found by the stress campaign (task 523: a 1.09 px PSF under the 1 px prior): the estimate
agreed with the prior within the 10 % re-measure tolerance, so every frame was fitted at
1 px and the running prior kept 1 px for good. Bright stars fitted too narrow lean and their
stated sigma is too small: at rest the published attitude's NEES mean was 10.8 (now 3.5).
Judged on an independently written renderer (bench/alt_renderer.py) against its truth.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid.psf.running_prior import RunningPsf

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package

SIZE_PX = 384
FLUXES_E = (3.0e4, 1.0e5)  # SNR ~ 250-900 at this sky: the stars whose sigma the width sets


def _normalised_errors(psf_sigma: float, seed: int) -> tuple[np.ndarray, list[float]]:
    """Bright isolated stars' (error / stated sigma)^2 per axis [-] and each frame's applied width [px]."""
    from bench import alt_renderer as alt

    rng = np.random.default_rng(seed)
    detector = alt.Detector(sky_e=40.0, read_noise_e=5.0, gain_e_per_adu=1.0, full_well_e=200000.0)
    running, squares, applied = RunningPsf(), [], []
    for flux in FLUXES_E * 3:
        x, y = alt.place_stars(SIZE_PX, SIZE_PX, 25, 30.0, 20.0, rng)
        frame = alt.render(alt.StarField.build(alt.GaussianPsf(psf_sigma), x, y), flux, detector, SIZE_PX, SIZE_PX, rng)
        spots = extract_spots(frame.image, CentroidConfig(), psf_prior=running.prior)
        running.update(spots.psf)
        applied.append(spots.psf.applied_sigma_px)
        nearest = np.hypot(x[:, None] - spots.x[None], y[:, None] - spots.y[None])
        star, spot = np.nonzero(nearest < 1.0)
        cov = spots.cov[spot]
        squares.extend(((spots.x[spot] - x[star]) ** 2 / cov[:, 0, 0]).tolist())
        squares.extend(((spots.y[spot] - y[star]) ** 2 / cov[:, 1, 1]).tolist())
    return np.asarray(squares), applied


@pytest.mark.parametrize("psf_sigma", [0.95, 1.06, 1.09])
def test_a_psf_near_the_prior_is_fitted_at_its_width(psf_sigma):
    """Applied width within 3 % of the truth; bright stars' mean (error / sigma)^2 within [0.6, 1.5] (1 expected)."""
    squares, applied = _normalised_errors(psf_sigma, seed=int(psf_sigma * 1000))
    assert squares.size >= 200
    # Before the fix the 1.06 and 1.09 px frames were all fitted at 1 px, their bright stars'
    # mean square 1.7-1.9.
    assert np.all(np.abs(np.asarray(applied[1:]) / psf_sigma - 1.0) < 0.03), applied
    assert 0.6 < float(np.mean(squares)) < 1.5, float(np.mean(squares))
