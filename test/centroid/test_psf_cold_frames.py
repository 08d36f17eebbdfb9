# SPDX-License-Identifier: Apache-2.0
"""
The PSF estimate on a frame measured cold (no running prior, the 1 px default prior).

Frames it once got wrong: unaided ~13.7 px streaks of a 1 px PSF (2 deg/s, 0.1 s, the
default camera and sensor) estimated as wide round stars; bright wide stars on a dark sky
whose estimate found no usable star (a chance tie of one star's top pixels was taken for the
sensor's clip level, which every equally bright star then reached); faint wide stars whose
PSF was estimated from short cosmic-ray tracks. Judged on the truth of the renderers: which
star made each spot.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from star_tracker.centroid import CentroidConfig, extract_spots

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package

# bench/bench_tracking.py's delay trial 4 at 2 deg/s: its pointing (rotation vector [rad]), body
# rate [rad/s] and frame seeds; frames 4 and 6 were estimated at sigma 3.4 and 3.8 px.
STREAK_POINTING = np.array([-2.124096887956665, -1.4445672972162755, 0.00473690026541621])
STREAK_RATE = np.array([-0.02246391686036641, 0.02630765649286521, -0.0046636175112017])
STREAK_SEED = 1691985944


def _found(spots, x: np.ndarray, y: np.ndarray, reach: float) -> np.ndarray:
    if len(spots) == 0:
        return np.zeros(x.size, bool)
    return np.hypot(x[:, None] - spots.x[None], y[:, None] - spots.y[None]).min(axis=1) < reach


def test_unaided_streaks_are_not_taken_for_wide_stars(catalog, nominal_camera):
    """
    Unaided frames of ~13.7 px streaks: the PSF stays at the optics' 1 px (estimated or the prior).

    Before: 5 of 10 fitted streaks passed the roundness test (axis ratios 1.4-2.6 under a
    round weight twice the round fit's width), the frame was measured at sigma 2.5-2.9 px and
    lost ~20 % of its spots. Judged also on the truth: the streaks of stars of >= 3000 e- are
    found (a spot within 3 px of the mid-exposure position).
    """
    from star_tracker.models.attitude import rotation_vector_to_matrix
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import KIND_STAR, StarFieldRenderer, frame_seed
    from star_tracker.sim.sensor import SensorModel

    renderer = StarFieldRenderer(nominal_camera, SensorModel(), catalog, magnitude_limit=7.5)
    motion = ConstantRateMotion(rotation_vector_to_matrix(STREAK_POINTING), STREAK_RATE)
    for k in (4, 6):
        frame = renderer.render(motion, 0.05 + 0.1 * k, frame_seed(STREAK_SEED, k))
        spots = extract_spots(frame.image, CentroidConfig())
        assert 0.8 <= spots.psf.applied_sigma_px <= 1.2, (k, spots.psf)
        t = frame.truth
        bright = (t.kind == KIND_STAR) & (t.electrons >= 3000) & (t.x > 12) & (t.x < 1011) & (t.y > 12) & (t.y < 1011)
        assert bright.sum() >= 20
        assert _found(spots, t.x[bright], t.y[bright], 3.0).mean() >= 0.9, k


def test_bright_wide_stars_on_a_dark_sky_are_estimated_from_the_narrow_prior():
    """
    Equal sigma 2.8 px stars of 30,000 e- on a dark sky (1 e-/px, read noise 2 e-), bench/alt_renderer.py.

    A wide star's top pixels are within a few noise sigmas of each other: one star's top had a
    3-pixel tie, taken as the frame's clip level; every star reached it, 1 of 39 was usable,
    the estimate fell back to the 1 px prior and the frame kept 3 of its 39 stars. A clip level
    is now the frame's only where no star reads above it.
    """
    from bench import alt_renderer as alt

    sigma = 2.8
    rng = np.random.default_rng([11, 0, 256, 28])
    x, y = alt.place_stars(256, 256, 60, 5 * sigma / alt.SIGMA_PER_FWHM, 3 * sigma + 8, rng)
    frame = alt.render(alt.StarField.build(alt.GaussianPsf(sigma), x, y), 30000.0,
                       alt.Detector(sky_e=1.0, read_noise_e=2.0), 256, 256, rng)
    spots = extract_spots(frame.image, CentroidConfig())
    assert spots.psf.estimated, spots.psf.reason
    assert abs(spots.psf.sigma_px - sigma) <= 0.1 * sigma
    assert x.size >= 30
    assert _found(spots, frame.truth.x, frame.truth.y, 2 * sigma + 1).mean() >= 0.95


def _faint_wide_stars_and_cosmic_rays():
    """
    bench/bench_psf_cold.py's alt frame at sigma 3 px, 1,000 e-, seed 4: 60 stars, 7 cosmic rays (5 short).

    Returns (image, truth).
    """
    from bench import alt_renderer as alt

    sigma, flux = 3.0, 1000.0
    detector = alt.Detector(sky_e=40.0, read_noise_e=5.0, gain_e_per_adu=1.0, hot_pixel_fraction=1e-4,
                            cosmic_rays_per_frame=3.0)
    rng = np.random.default_rng([4100, 4, 300, 1000, 40])
    x, y = alt.place_stars(512, 512, 60, max(5 * sigma / alt.SIGMA_PER_FWHM, 12.0), 3 * sigma + 8, rng)
    frame = alt.render(alt.StarField.build(alt.GaussianPsf(sigma), x, y), flux, detector, 512, 512, rng)
    return frame.image, frame.truth


def test_faint_wide_stars_are_not_estimated_from_short_cosmic_rays():
    """
    Faint sigma-3 px stars (SNR ~10: none usable at the 1 px prior) and 7 cosmic rays, 5 of them usable.

    Before: the estimate took the 5 short tracks for the PSF (sigma 0.73 px, minor axis 0.58),
    the frame was measured at 0.58 px and kept 39 of its 59 scored stars. Most detections read
    far wider than that estimate: the wider priors are tried, with the tracks left out.
    """
    image, t = _faint_wide_stars_and_cosmic_rays()
    assert int(t.defect_is_cosmic_ray.sum()) >= 5  # the frame still holds what misled the estimate
    spots = extract_spots(image, CentroidConfig())
    assert spots.psf.estimated, spots.psf.reason
    # Within 0.3 px, or 2 of the estimate's own sigmas: with hot pixels' readings no longer
    # ranked as peaks, it comes from 11 faint stars (2.65 +- 0.27 px).
    reach = max(0.3, 2.0 * spots.psf.sigma_uncertainty_px)
    assert abs(spots.psf.sigma_px - 3.0) <= reach and abs(spots.psf.applied_sigma_px - 3.0) <= reach, spots.psf
    scored = t.snr >= 10.0
    near = np.hypot(t.x[:, None] - t.defect_x[None], t.y[:, None] - t.defect_y[None]) \
        < 3 * 3.0 + 3 + 0.5 * t.defect_extent_px[None]
    scored &= ~near.any(axis=1)
    assert scored.sum() >= 50
    assert _found(spots, t.x[scored], t.y[scored], 2 * 3.0 + 1).mean() >= 0.9


@pytest.mark.xfail(strict=True, reason="the frame no longer leads the estimate at the prior to its 5 cosmic-ray "
                   "tracks (a cleaned pixel's reading is no longer its peak, so they rank below the stars): the "
                   "contradicted estimate is not reached; a frame that reaches it is still to be built")
@pytest.mark.parametrize("wider", ["none", "from fewer stars"])
def test_a_contradicted_estimate_stands_when_no_wider_width_gives_a_better_one(monkeypatch, wider):
    """The same frame with the wider priors' estimates failing, or from fewer stars: the tracks' estimate is kept."""
    from star_tracker.centroid import psf_loop
    from star_tracker.centroid.psf.estimate import PsfEstimate

    estimate = psf_loop.estimate_psf

    def weak_faint_estimate(image, frame, prior, gain, faint=False, **kwargs):
        if not faint:
            return estimate(image, frame, prior, gain, faint, **kwargs)
        if wider == "none":
            return PsfEstimate.assumed(prior, "prior", "test: none")
        return PsfEstimate(3.0, 3.0, 3.0, 0.0, 0.1, 4, "estimated")

    monkeypatch.setattr(psf_loop, "estimate_psf", weak_faint_estimate)
    image, _ = _faint_wide_stars_and_cosmic_rays()
    spots = extract_spots(image, CentroidConfig())
    assert spots.psf.estimated and spots.psf.sigma_px < 1.0 and spots.psf.stars == 5, spots.psf
    assert spots.psf.applied_sigma_px == pytest.approx(spots.psf.sigma_minor_px)


@pytest.mark.slow
def test_an_estimate_the_running_prior_agrees_with_stands_beside_a_cloud_banks_wide_detections(monkeypatch):
    """
    A real photograph's stars under a cloud bank (granasat IMG_007985, `star-tracker solve`).

    Its second measurement, at the running prior 0.58 px, estimates 0.53 px from 11 stars while
    most detections (the clouds) read over twice as wide. The running prior corroborates it: no
    wider width is measured (one that took the wider priors' estimate, 0.83 px from 7 sources,
    matched 25 stars, not 44).
    """
    from bench import corpus

    try:
        image = corpus.load_corpus(corpus.find_corpus(), ["gran_IMG_007985"])[0]
    except (corpus.CorpusMissing, IndexError):
        pytest.skip("real-image corpus or gran_IMG_007985 absent (../shared/realdata)")
    from star_tracker.centroid import psf_loop

    widths = []
    measure = psf_loop.measure_frame

    def recording(image_, config, trial, *args, **kwargs):
        widths.append(trial.sigma_px)
        return measure(image_, config, trial, *args, **kwargs)

    monkeypatch.setattr(psf_loop, "measure_frame", recording)
    code, record, _, err = corpus.run_solve_command(corpus.solve_argv(image))
    assert code == 0, err[-300:]
    assert max(widths) <= 1.0, widths  # the prior and the estimate; no wider width tried
    assert record["psf"]["sigma_px"] < 0.7, record["psf"]
    assert len(record["matched"]) >= 40
