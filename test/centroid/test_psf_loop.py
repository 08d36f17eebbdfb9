# SPDX-License-Identifier: Apache-2.0
"""
The PSF loop (centroid/psf_loop.py): which PSFs a frame is measured with, and what the spots say of it.

Frames of the second renderer (bench/alt_renderer.py, independent of our simulator) whose PSF
is known: the loop must settle on a width within 10 % of the truth (a ring's round fit reads
wider than its second moments: within 35 %), measure the frame with the
widths its steps call for (recorded at measure_frame), always with the user's CentroidConfig
unchanged (the width under trial travels in PsfTrial), and return spots whose PSF record names
the width the kept measurement used.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid import psf_loop

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import alt_renderer as alt  # noqa: E402

SIZE = 384
DETECTOR = alt.Detector(sky_e=40.0, read_noise_e=5.0, hot_pixel_fraction=1e-4, cosmic_rays_per_frame=3.0)


def frame(psf, flux: float, stars: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x, y = alt.place_stars(SIZE, SIZE, stars, 12.0, 3 * psf.equivalent_sigma_px + 8, rng)
    return alt.render(alt.StarField.build(psf, x, y), flux, DETECTOR, SIZE, SIZE, rng).image


def measured_trials(monkeypatch, image, config=CentroidConfig(), **kwargs):
    """Run extract_spots, recording (trial, config) of every measurement the loop makes."""
    trials = []
    measure = psf_loop.measure_frame

    def recording(image_, config_, trial, *args, **kw):
        trials.append((trial, config_))
        return measure(image_, config_, trial, *args, **kw)

    monkeypatch.setattr(psf_loop, "measure_frame", recording)
    return extract_spots(image, config, **kwargs), trials


@pytest.mark.parametrize("name, psf, flux, stars, widths, tolerance", [
    # Round stars at the prior: measured once.
    ("at the prior", alt.GaussianPsf(1.0), 5000.0, 40, [1.0], 0.1),
    # Wide stars: measured at the prior, estimated, measured again at the estimate.
    ("wide", alt.GaussianPsf(3.0), 30000.0, 40, [1.0, 3.0], 0.1),
    # Faint wide rings: too few usable stars at the prior; the wider-prior search (2x) finds them.
    ("faint rings", alt.AnnulusPsf.with_equivalent_sigma(3.0), 2000.0, 60, [1.0, 2.0, 3.0], 0.35),
    # Astigmatic stars narrower across than the prior: measured again at the prior, width test at the minor axis.
    ("astigmatic", alt.EllipticalGaussianPsf(1.3, 1.0 / 1.3, np.radians(30.0)), 5000.0, 40, [1.0, 1.0], 0.1),
])
def test_the_loop_measures_the_widths_its_steps_call_for_and_settles_on_the_truth(
        monkeypatch, name, psf, flux, stars, widths, tolerance):
    config = CentroidConfig()
    spots, trials = measured_trials(monkeypatch, frame(psf, flux, stars, seed=len(name)), config)
    assert all(used is config for _, used in trials), "the user's config travels unchanged"
    tried = [trial.sigma_px for trial, _ in trials]
    assert tried == pytest.approx(widths, rel=tolerance), tried
    assert spots.psf.estimated
    truth = psf.equivalent_sigma_px
    assert spots.psf.sigma_px == pytest.approx(truth, rel=tolerance)
    assert spots.psf.applied_sigma_px == trials[-1][0].sigma_px  # the kept measurement is the last one
    assert len(spots) >= 0.8 * stars
    if name == "astigmatic":
        assert trials[-1][0].narrowest_px == pytest.approx(1.0 / 1.3, rel=0.15)
        assert trials[-1][0].elliptical is not None and spots.fit_model == "elliptical"
    if name == "faint rings":
        assert trials[-1][0].rings and spots.psf.annular


def test_a_running_prior_is_measured_first_and_kept_when_the_estimate_agrees(monkeypatch):
    image = frame(alt.GaussianPsf(2.0), 20000.0, 40, seed=7)
    cold, cold_trials = measured_trials(monkeypatch, image)
    assert [t.sigma_px for t, _ in cold_trials][0] == 1.0 and len(cold_trials) == 2
    warm, trials = measured_trials(monkeypatch, image, psf_prior=cold.psf.applied_sigma_px)
    assert [t.sigma_px for t, _ in trials] == [cold.psf.applied_sigma_px]
    assert np.array_equal(warm.x, cold.x) and np.array_equal(warm.cov, cold.cov)


def test_fixed_mode_and_a_rate_aided_frame_measure_once_and_say_why(monkeypatch):
    image = frame(alt.GaussianPsf(2.0), 20000.0, 40, seed=8)
    spots, trials = measured_trials(monkeypatch, image, CentroidConfig(psf_mode="fixed", psf_sigma_px=1.5))
    assert [t.sigma_px for t, _ in trials] == [1.5]
    assert spots.psf.source == "configured" and spots.psf.applied_sigma_px == 1.5
    empty = np.full((64, 64), 100, np.uint16)
    spots, trials = measured_trials(monkeypatch, empty)
    assert len(trials) == 1 and len(spots) == 0
    assert spots.psf.source == "prior" and spots.psf.reason == "no detections"
