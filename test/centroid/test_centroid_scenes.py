# SPDX-License-Identifier: Apache-2.0
"""
Centroider on purpose-built scenes (stars placed at chosen pixels, rendered by the simulator).

Blends, hot pixels next to stars, the selectable methods, straight and curved streaks, and the
rate aid. Every check is against the simulator's truth.
"""
from __future__ import annotations

import numpy as np
import pytest

from star_tracker.models.attitude import radec_roll_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.models.catalog import StarCatalog, unit_to_radec
from star_tracker.centroid import (FLAG_BLENDED, FLAG_RATE_AIDED, FLAG_SATURATED, FLAG_STREAK, CENTROID_METHODS,
                                   CentroidConfig, extract_spots)
from star_tracker.centroid.psf import point_fits
from star_tracker.centroid.streak import rate_aid
from star_tracker.centroid.detection import saturation
from star_tracker.centroid.streak import streak_spots
from star_tracker.centroid.streak.smear import SmearModel
from star_tracker.sim.motion import ConstantRateMotion, SlewMotion
from star_tracker.sim.render import KIND_HOT_PIXEL, StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel

CAMERA = CameraModel.from_fov(1024, 1024, np.radians(15.0))
POINTING = radec_roll_to_matrix(1.0, 0.3, 0.0)
EXPOSURE = 0.1


def render_stars(x, y, electrons, sensor=SensorModel(), rate=(0.0, 0.0, 0.0), seed=0):
    """
    Return a frame with stars of `electrons` [e-] whose mid-exposure images fall at pixels (x, y).

    Returns the frame; truth is sorted back to the input order (truth.hip = index + 1).
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    ra, dec = unit_to_radec(CAMERA.pixel_to_ray(x, y) @ POINTING.T)
    hp = -2.5 * np.log10(np.asarray(electrons, float) / (sensor.zero_point_e_per_s * sensor.exposure_s))
    n = x.size
    catalog = StarCatalog(hip=np.arange(1, n + 1, dtype=np.int32), ra=ra, dec=dec, pm_ra=np.zeros(n),
                          pm_dec=np.zeros(n), hp=np.broadcast_to(hp, (n,)).copy(), b_v=np.zeros(n), epoch_jyear=2026.0)
    renderer = StarFieldRenderer(CAMERA, sensor, catalog, magnitude_limit=30.0)
    return renderer.render(ConstantRateMotion(POINTING, np.asarray(rate, float)), 1.0, frame_seed(seed, 0))


def star_truth(frame):
    t = frame.truth
    stars = np.flatnonzero(t.kind == 0)
    order = stars[np.argsort(t.hip[stars])]
    return t.x[order], t.y[order]


def nearest(spots, tx, ty):
    d = np.hypot(tx[:, None] - spots.x[None], ty[:, None] - spots.y[None])
    return d.argmin(axis=1), d.min(axis=1)


def grid(n_side, spacing, start, rng):
    cx, cy = np.meshgrid(start + spacing * np.arange(n_side), start + spacing * np.arange(n_side))
    return cx.ravel() + rng.uniform(-0.5, 0.5, cx.size), cy.ravel() + rng.uniform(-0.5, 0.5, cy.size)


@pytest.mark.parametrize("separation_px, ratio", [(5.0, 1.0), (5.0, 0.4), (7.0, 0.4)])
def test_blended_pairs_are_split_into_both_stars(separation_px, ratio):
    rng = np.random.default_rng(int(separation_px * 10 + ratio * 100))
    cx, cy = grid(7, 130, 100, rng)
    angle = rng.uniform(0, np.pi, cx.size)
    x = np.column_stack([cx, cx + separation_px * np.cos(angle)]).ravel()
    y = np.column_stack([cy, cy + separation_px * np.sin(angle)]).ravel()
    electrons = np.tile([20000.0, 20000.0 * ratio], cx.size)
    frame = render_stars(x, y, electrons, seed=3)
    tx, ty = star_truth(frame)
    spots = extract_spots(frame.image, CentroidConfig())
    index, distance = nearest(spots, tx, ty)
    found = distance < 0.2
    assert found[0::2].mean() >= 0.95 and found[1::2].mean() >= 0.95  # both stars of (nearly) every pair
    assert np.all(spots.flags[index[found]] & FLAG_BLENDED)
    # Without splitting, a pair is one spot between the stars: neither star is measured.
    merged = extract_spots(frame.image, CentroidConfig(split_blends=False))
    assert len(merged) <= cx.size + 2
    assert nearest(merged, tx, ty)[1].max() > 1.0


def test_a_star_next_to_a_hot_pixel_is_measured_and_the_hot_pixel_is_not():
    sensor = SensorModel(hot_pixel_fraction=1e-4, hot_pixel_dark_factor=3000.0)  # hot pixels of ~6000 e-
    probe = render_stars([512.0], [512.0], [1.0], sensor=sensor).truth
    hot = (probe.kind == KIND_HOT_PIXEL) & (np.minimum(probe.x, probe.y) > 20) & (np.maximum(probe.x, probe.y) < 1000)
    hx, hy = probe.x[hot][:40], probe.y[hot][:40]
    assert hx.size == 40
    rng = np.random.default_rng(11)
    for separation in (2.0, 3.0, 5.0):
        angle = rng.uniform(0, 2 * np.pi, hx.size)
        frame = render_stars(hx + separation * np.cos(angle), hy + separation * np.sin(angle),
                             np.full(hx.size, 3000.0), sensor=sensor, seed=5)  # stars ~2x fainter than the pixel
        tx, ty = star_truth(frame)
        spots = extract_spots(frame.image, CentroidConfig())
        _, distance = nearest(spots, tx, ty)
        assert np.mean(distance < 0.3) >= 0.95, separation
        t = frame.truth
        hot_x, hot_y = t.x[t.kind == KIND_HOT_PIXEL], t.y[t.kind == KIND_HOT_PIXEL]
        on_hot = np.hypot(spots.x[:, None] - hot_x[None], spots.y[:, None] - hot_y[None]).min(axis=1) < 1.0
        on_star = np.hypot(spots.x[:, None] - tx[None], spots.y[:, None] - ty[None]).min(axis=1) < 1.0
        assert not np.any(on_hot & ~on_star)


def test_every_method_is_selectable_and_the_psf_fit_is_the_most_accurate():
    rng = np.random.default_rng(2)
    x, y = grid(8, 120, 80, rng)
    frame = render_stars(x, y, np.full(x.size, 8000.0), seed=9)
    tx, ty = star_truth(frame)
    rms = {}
    for method in CENTROID_METHODS:
        spots = extract_spots(frame.image, CentroidConfig(method=method))
        _, distance = nearest(spots, tx, ty)
        assert np.all(distance < 0.5), method
        rms[method] = float(np.sqrt(np.mean(distance ** 2)))
    assert rms["auto"] == pytest.approx(rms["gaussian"])  # no streaks here: auto is the PSF fit
    assert rms["gaussian"] < rms["wcog"] < rms["cog"]
    assert rms["gaussian"] < 0.05


def straight_streak_frame(smear_px, electrons, seed):
    rng = np.random.default_rng(seed)
    x, y = grid(7, 130, 110, rng)
    rate = (smear_px / (EXPOSURE * CAMERA.fy), 0.5 * smear_px / (EXPOSURE * CAMERA.fx), 0.0)  # x and y motion
    return render_stars(x, y, np.full(x.size, electrons), rate=rate, seed=seed), np.array(rate)


def test_straight_streaks_give_the_mid_exposure_position_length_and_direction():
    frame, rate = straight_streak_frame(20.0, 30000.0, seed=4)
    tx, ty = star_truth(frame)
    spots = extract_spots(frame.image, CentroidConfig())
    index, distance = nearest(spots, tx, ty)
    assert np.all(spots.flags[index] & FLAG_STREAK)
    # Positions: the fit's covariance describes the errors (normalized errors ~ unit variance).
    ex, ey = spots.x[index] - tx, spots.y[index] - ty
    cov = spots.cov[index]
    normalized = np.concatenate([ex / np.sqrt(cov[:, 0, 0]), ey / np.sqrt(cov[:, 1, 1])])
    assert 0.7 < np.std(normalized) < 1.4 and np.sqrt(np.mean(distance ** 2)) < 0.1
    # Length and direction of the smear: the image moves by -omega x s, i.e. +y for omega_x.
    truth_vectors = SmearModel(CAMERA, rate, EXPOSURE).smear_vectors(tx, ty)
    assert np.allclose(spots.streak_length[index], np.linalg.norm(truth_vectors, axis=1), rtol=0.03)
    truth_angle = np.arctan(truth_vectors[:, 1] / truth_vectors[:, 0])  # undirected without the rate
    angle_error = np.angle(np.exp(2j * (spots.streak_angle[index] - truth_angle))) / 2
    assert np.degrees(np.max(np.abs(angle_error))) < 1.0


def test_curved_roll_streaks_are_measured_on_the_predicted_arc():
    rng = np.random.default_rng(6)
    # Two rings far from the boresight (25-35 px arcs along the ring, 70+ px apart).
    radius = np.repeat([350.0, 470.0], 20) + rng.uniform(-5, 5, 40)
    phase = np.r_[np.arange(20), np.arange(20) + 0.5] * (2 * np.pi / 20) + rng.uniform(-0.05, 0.05, 40)
    x, y = CAMERA.cx + radius * np.cos(phase), CAMERA.cy + radius * np.sin(phase)
    rate = np.array([0.0, 0.0, np.radians(40.0)])  # roll 40 deg/s: arcs of 0.07 rad
    frame = render_stars(x, y, np.full(x.size, 200000.0), rate=rate, seed=8)
    tx, ty = star_truth(frame)
    smear = SmearModel(CAMERA, rate, EXPOSURE)
    aided = extract_spots(frame.image, CentroidConfig(), smear)
    index, distance = nearest(aided, tx, ty)
    assert np.all(aided.flags[index] & (FLAG_STREAK | FLAG_RATE_AIDED) == FLAG_STREAK | FLAG_RATE_AIDED)
    rms_aided = np.sqrt(np.mean(distance ** 2))
    # The arc's mid-point, not its chord's: a straight-segment fit and the centre of gravity sit
    # off the arc (sagitta ~ L^2 / (8 R) ~ 0.25 px).
    _, free = nearest(extract_spots(frame.image, CentroidConfig()), tx, ty)
    _, cog = nearest(extract_spots(frame.image, CentroidConfig(method="cog")), tx, ty)
    assert rms_aided < 0.03
    assert np.sqrt(np.mean(free ** 2)) > 3 * rms_aided and np.sqrt(np.mean(cog ** 2)) > 3 * rms_aided


def test_the_rate_aid_finds_faint_streaks_the_blind_search_misses():
    # SNR 20 as a point source, smeared over 20 px: the matched streak filter sees it at ~10 sigma.
    frame, rate = straight_streak_frame(20.0, 1150.0, seed=12)
    tx, ty = star_truth(frame)
    config = CentroidConfig()
    _, blind = nearest(extract_spots(frame.image, config), tx, ty)
    aided_spots = extract_spots(frame.image, config, SmearModel(CAMERA, rate, EXPOSURE))
    index, aided = nearest(aided_spots, tx, ty)
    assert np.mean(aided < 2.0) >= 0.9 and np.mean(blind < 2.0) < 0.5
    assert np.all(aided_spots.flags[index[aided < 2.0]] & FLAG_RATE_AIDED)


def test_smeared_real_sky_spots_have_honest_covariances(catalog, nominal_camera):
    # 1.5 deg/s with some roll: ~10 px streaks, faint ones included. A streak measured as a point
    # (or a blend as one star) would be off by many of its claimed sigmas and pull the attitude.
    renderer = StarFieldRenderer(nominal_camera, SensorModel(), catalog, magnitude_limit=7.5)
    motion = ConstantRateMotion(radec_roll_to_matrix(1.4, 0.35, 0.2), np.radians([1.2, 0.9, 0.2]))
    squared = []
    for k in range(3):
        frame = renderer.render(motion, 10.0 + k, frame_seed(0, k))
        spots = extract_spots(frame.image, CentroidConfig(saturation_adu=60000.0))
        t = frame.truth
        sx, sy = t.x[t.kind == 0], t.y[t.kind == 0]
        d = np.hypot(spots.x[:, None] - sx[None], spots.y[:, None] - sy[None])
        use = (d.min(axis=1) < 3.0) & (spots.snr >= 10) & ((spots.flags & 2) == 0)
        j = d.argmin(axis=1)[use]
        ex, ey, c = spots.x[use] - sx[j], spots.y[use] - sy[j], spots.cov[use]
        squared.extend((c[:, 1, 1] * ex * ex - 2 * c[:, 0, 1] * ex * ey + c[:, 0, 0] * ey * ey)
                       / (c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] ** 2))
    squared = np.array(squared)
    assert squared.size >= 200
    assert np.mean(squared > 25.0) <= 0.01  # Mahalanobis distance > 5: at most 1 %
    assert 1.5 < np.mean(squared[squared <= 25.0]) < 3.0  # chi-square with 2 DOF: mean 2


def chi2_of(spots, index, tx, ty):
    """Squared Mahalanobis distance of each spot `index` from the truth under its covariance."""
    e = np.stack([spots.x[index] - tx, spots.y[index] - ty], axis=1)
    return np.einsum("ni,nij,nj->n", e, np.linalg.inv(spots.cov[index]), e)


@pytest.mark.parametrize("rate_deg_s", [(0.0, 0.0, 0.0), (0.5, 0.2, 0.0)])
def test_clipped_stars_are_flagged_by_their_flat_top_and_keep_an_honest_covariance(rate_deg_s):
    # Default config: saturation_adu = 0 (the uint16 maximum, 65535), but the default sensor clips
    # at full well 60000 e- + 100 ADU bias. Every other star peaks ~8x over the full well, the
    # rest at ~0.8x: only the first are flagged; fitted without their clipped core, their
    # positions stay within their (larger) covariances. As points or as 3.6 px streaks.
    rng = np.random.default_rng(14)
    x, y = grid(8, 120, 80, rng)
    electrons = np.where(np.arange(x.size) % 2 == 0, 3.0e6, 3.0e5)
    rate = np.radians(rate_deg_s)
    frame = render_stars(x, y, electrons, rate=rate, seed=15)
    tx, ty = star_truth(frame)
    smear = SmearModel(CAMERA, rate, EXPOSURE) if np.any(rate) else None
    spots = extract_spots(frame.image, CentroidConfig(), smear)
    index, distance = nearest(spots, tx, ty)
    assert np.all(distance < 0.5)
    clipped = electrons > 1e6
    flagged = (spots.flags[index] & FLAG_SATURATED) != 0
    assert np.array_equal(flagged, clipped)
    chi2 = chi2_of(spots, index, tx, ty)
    assert chi2[clipped].max() < 25.0 and chi2[clipped].mean() < 4.0
    assert chi2[~clipped].mean() < 4.0
    assert np.all(np.sqrt(spots.cov[index[clipped], 0, 0]) < 0.2)  # still well measured, from the wings


@pytest.mark.parametrize("rate_deg_s", [(0.0, 0.0, 0.0), (0.0, 0.0, 3.0)])
def test_stars_clipped_in_one_or_two_pixels_are_found_by_their_fits(rate_deg_s, monkeypatch):
    # 1.1-1.4x the full well at the peak: one or two clipped pixels, mostly no flat top. The fit
    # gives them away (the model exceeds the clipped pixel by many sigmas); refitted without
    # it, the positions keep honest covariances. Without that test they are many sigmas off.
    rng = np.random.default_rng(18)
    x, y = grid(8, 120, 80, rng)
    rate = np.radians(rate_deg_s)
    frame = render_stars(x, y, np.full(x.size, 5.5e5), rate=rate, seed=19)
    tx, ty = star_truth(frame)
    smear = SmearModel(CAMERA, rate, EXPOSURE) if np.any(rate) else None
    spots = extract_spots(frame.image, CentroidConfig(), smear)
    index, distance = nearest(spots, tx, ty)
    assert np.all(distance < 0.5)
    assert np.mean((spots.flags[index] & FLAG_SATURATED) != 0) >= 0.75
    chi2 = chi2_of(spots, index, tx, ty)
    assert chi2.mean() < 3.0 and chi2.max() < 25.0
    monkeypatch.setattr(saturation, "UNDERSHOOT_SIGMA", np.inf)
    # (and without the misfit fallback, which would hand a badly fitted clipped star its centre of gravity)
    monkeypatch.setattr(point_fits, "MISFIT_CHI2", np.inf)
    unchecked = extract_spots(frame.image, CentroidConfig(), smear)
    index, _ = nearest(unchecked, tx, ty)
    assert chi2_of(unchecked, index, tx, ty).mean() > 4.0


def test_merged_streaks_on_the_predicted_path_are_fitted_as_two_stars(monkeypatch):
    # Pairs 2.5 px apart across a 14 px smear (one detection each): a one-star fit sits between
    # the two, many of its sigmas off; two stars on the predicted path recover both. Every star
    # of this field has such a companion, so the width across its streaks (streak.streak_width)
    # would be the pairs' spread: the split is examined at the rendered PSF, fixed.
    config = CentroidConfig(psf_mode="fixed", psf_sigma_px=1.0)
    rng = np.random.default_rng(16)
    cx, cy = grid(7, 130, 110, rng)
    rate = np.array([0.0, 14.0 / (EXPOSURE * CAMERA.fy), 0.0])  # image moves 14 px along x
    offset = np.column_stack([rng.uniform(-4.0, 4.0, cx.size), rng.choice([-2.5, 2.5], cx.size)])
    x = np.column_stack([cx, cx + offset[:, 0]]).ravel()
    y = np.column_stack([cy, cy + offset[:, 1]]).ravel()
    electrons = np.tile([30000.0, 15000.0], cx.size)
    frame = render_stars(x, y, electrons, rate=rate, seed=17)
    tx, ty = star_truth(frame)
    smear = SmearModel(CAMERA, rate, EXPOSURE)
    spots = extract_spots(frame.image, config, smear)
    index, distance = nearest(spots, tx, ty)
    found = distance < 0.5
    assert found.mean() >= 0.95
    assert np.all(spots.flags[index[found]] & FLAG_BLENDED)
    chi2 = chi2_of(spots, index[found], tx[found], ty[found])
    assert chi2.mean() < 3.0 and np.mean(chi2 > 16.0) < 0.03
    # Without the split, each pair is one spot between its stars.
    monkeypatch.setattr(streak_spots, "MERGED_MIN_SNR", np.inf)
    single = extract_spots(frame.image, config, smear)
    index, distance = nearest(single, tx, ty)
    assert np.median(chi2_of(single, index, tx, ty)) > 25.0


def test_a_strong_stray_light_gradient_neither_hides_stars_nor_makes_false_ones():
    # Stray light rising by 4000 e-/px/s across the frame (400 e- per pixel in 0.1 s, about
    # 10x the sky background at the far corner): the background mesh must follow it.
    rng = np.random.default_rng(21)
    x, y = grid(8, 120, 80, rng)
    sensor = SensorModel(stray_light_gradient_e_per_px2_s=(3.0, 1.0))
    frame = render_stars(x, y, np.full(x.size, 1500.0), sensor=sensor, seed=13)  # SNR ~15 stars
    tx, ty = star_truth(frame)
    spots = extract_spots(frame.image, CentroidConfig())
    _, distance = nearest(spots, tx, ty)
    assert np.mean(distance < 0.5) >= 0.98
    assert len(spots) <= x.size + 1


@pytest.mark.parametrize("seed", [0, 1])
def test_a_rate_aid_the_streaks_disagree_with_is_dropped_for_the_frame(catalog, seed, monkeypatch):
    # An identifier's rate lagging a 1 deg/s^2 ramp by ~30 % (5 Hz frames), used as the aid:
    # the path fits locked onto one end of the streaks (a common along-track bias of 1-2 px,
    # 100" in the attitude, with sub-arcsecond covariances) and split streaks into extra spots.
    motion = SlewMotion(radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.0), [0.6, 0.8, 0.0],
                        np.radians(8.0), np.radians(2.0), np.radians(1.0))
    t = 1.55  # 1.55 deg/s, still accelerating
    frame = StarFieldRenderer(CAMERA, SensorModel(), catalog.at_epoch(2026.0), magnitude_limit=7.5).render(
        motion, t, frame_seed(seed, 0))
    rate = motion.angular_velocity_at(t)
    along = SmearModel(CAMERA, rate, EXPOSURE).smear_vectors([512.0], [512.0])[0]
    along /= np.linalg.norm(along)
    stars = frame.truth.kind == 0
    tx, ty = frame.truth.x[stars], frame.truth.y[stars]

    def along_track_bias(spots):
        d = np.hypot(spots.x[:, None] - tx[None], spots.y[:, None] - ty[None])
        j, bright = d.argmin(axis=1), (d.min(axis=1) < 4.0) & (spots.snr > 30)
        return np.median(np.column_stack([spots.x - tx[j], spots.y - ty[j]])[bright] @ along), bright.sum()

    right = extract_spots(frame.image, CentroidConfig(), SmearModel(CAMERA, rate, EXPOSURE))
    lagging = extract_spots(frame.image, CentroidConfig(), SmearModel(CAMERA, 0.68 * rate, EXPOSURE))
    assert not right.rate_aid_rejected and lagging.rate_aid_rejected
    assert abs(len(lagging) - len(right)) <= 0.05 * len(right)  # no split streaks
    for spots in (right, lagging):
        bias, bright = along_track_bias(spots)
        assert abs(bias) < 0.15 and bright >= 25, (bias, bright)
    # Without the check, the lagging aid gives the biased, fragmented frame.
    monkeypatch.setattr(rate_aid, "AID_TOLERANCE_FRACTION", np.inf)
    trusted = extract_spots(frame.image, CentroidConfig(), SmearModel(CAMERA, 0.68 * rate, EXPOSURE))
    bias, bright = along_track_bias(trusted)
    assert len(trusted) > 1.2 * len(right) and abs(bias) > 0.5, (len(trusted), len(right), bias)
