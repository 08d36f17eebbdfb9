# SPDX-License-Identifier: Apache-2.0
"""
One spot per star in rate-aided frames.

Two detections of one streak (the threshold cutting it in two, or a hot pixel's or a cosmic
ray's detection beside it whose window holds the star's light) are both fitted on the
predicted path and converge onto the same star: streak_spots.one_fit_per_star keeps one.
Judged against the simulator's truth (which star made each spot).
"""
from __future__ import annotations

import numpy as np
import pytest

from star_tracker.campaign.stress_faults import FAULT_KINDS, FrameSource, plan_stress
from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid.streak.fit_common import StreakImage
from star_tracker.centroid.streak.path_fit import fit_streaks_on_path
from star_tracker.centroid.streak.smear import SmearModel
from star_tracker.centroid.streak.streak_spots import one_fit_per_star
from star_tracker.models.attitude import radec_roll_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.models.catalog import StarCatalog, unit_to_radec
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import KIND_STAR, StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel

EXPOSURE = 0.1
COINCIDENT_PX = 0.05  # two spots closer than this are one star reported twice


@pytest.fixture(scope="module")
def source():
    return FrameSource()


def closest_pair(spots) -> float:
    """Smallest distance [px] between two spots of a frame."""
    xy = np.column_stack([spots.x, spots.y])
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1)) + np.eye(len(xy)) * 1e9
    return float(d.min()) if len(xy) > 1 else np.inf


def truth_chi2(spots, truth) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per spot: the nearest rendered star (index into the stars), its distance [px] and chi^2 in the spot's cov."""
    star = truth.kind == KIND_STAR
    tx, ty = truth.x[star], truth.y[star]
    d = np.hypot(spots.x[:, None] - tx[None], spots.y[:, None] - ty[None])
    near = d.argmin(axis=1)
    offset = np.column_stack([tx[near] - spots.x, ty[near] - spots.y])
    chi2 = np.einsum("ni,ni->n", offset, np.linalg.solve(spots.cov, offset[:, :, None])[:, :, 0])
    return near, d[np.arange(len(spots)), near], chi2


def test_two_starts_on_one_streak_give_one_fit():
    # One 9 px streak; the path fit started from both its ends (two detections of it) ends on
    # the star twice: one fit stands for it, at the truth within its covariance.
    camera = CameraModel.from_fov(256, 256, np.radians(4.0))
    pointing = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.3)
    sensor = SensorModel(full_well_e=1e8, gain_e_per_adu=4.0, exposure_s=EXPOSURE)
    ra, dec = unit_to_radec(camera.pixel_to_ray(np.array([128.3]), np.array([120.6])) @ pointing.T)
    hp = -2.5 * np.log10(40000.0 / (sensor.zero_point_e_per_s * EXPOSURE))
    catalog = StarCatalog(hip=np.array([1], np.int32), ra=ra, dec=dec, pm_ra=np.zeros(1), pm_dec=np.zeros(1),
                          hp=np.full(1, hp), b_v=np.zeros(1), epoch_jyear=2026.0)
    rate = 9.0 / (EXPOSURE * camera.fy) * np.array([np.sin(0.5), -np.cos(0.5), 0.0])
    renderer = StarFieldRenderer(camera, sensor, catalog, magnitude_limit=30.0)
    frame = renderer.render(ConstantRateMotion(pointing, rate), 1.0, frame_seed(7, 0))
    residual = frame.image.astype(np.float64) - (renderer.static_e / sensor.gain_e_per_adu + sensor.bias_adu)
    gain = sensor.gain_e_per_adu
    noise = float(np.sqrt((np.median(renderer.static_e) + sensor.read_noise_e ** 2) / gain ** 2 + 1.0 / 12.0))
    image = StreakImage(residual, sensor.psf_sigma_px, noise, gain)
    smear = SmearModel(camera, rate, EXPOSURE)
    tx, ty = float(frame.truth.x[0]), float(frame.truth.y[0])
    half = 0.5 * smear.smear_vectors(np.array([tx]), np.array([ty]))[0]
    # Both ends of the streak, and a star-free place far from it (it stays its own fit or fails).
    x0 = np.array([tx - half[0], tx + half[0], tx + 60.0])
    y0 = np.array([ty - half[1], ty + half[1], ty])
    path = smear.path(x0, y0)
    fit = fit_streaks_on_path(image, x0, y0, np.zeros(3), path)
    assert fit.converged[:2].all() and np.hypot(fit.x[0] - fit.x[1], fit.y[0] - fit.y[1]) < 0.5
    one, _, duplicate = one_fit_per_star(image, fit, x0, y0, path, smear)
    assert duplicate.tolist()[:2] in ([True, False], [False, True]) and not duplicate[2]
    kept = int(np.flatnonzero(~duplicate[:2])[0])
    assert one.converged[kept] and not one.converged[1 - kept]
    offset = np.array([one.x[kept] - tx, one.y[kept] - ty])
    assert offset @ np.linalg.solve(one.cov[kept], offset) < 16.0


def test_the_hot_pixel_storm_tumble_frame_reports_each_star_once(source):
    # A 1.45 deg/s tumble in a hot-pixel storm: a hot pixel's detection beside a 9.2 px streak
    # held the streak's light in its window and its path fit ended on the star as well:
    # (175.6626, 438.6351) and (175.6566, 438.6401), flux 913.6 and 912.6 ADU.
    plan = plan_stress(30, 3, required=FAULT_KINDS)
    mission = plan.missions[0]
    assert mission.motion_kind == "tumble" and mission.environment == "hot_pixel_storm"
    frame = next(f for f in mission.frames if f.index == 26)
    rendered = source.render(mission, frame)
    spots = extract_spots(rendered.image, CentroidConfig(), SmearModel(source.camera, rendered.truth.body_rate,
                                                                       EXPOSURE))
    assert closest_pair(spots) > COINCIDENT_PX
    near, distance, chi2 = truth_chi2(spots, rendered.truth)
    at_star = np.flatnonzero(np.hypot(spots.x - 175.646, spots.y - 438.665) < 1.0)
    assert at_star.size == 1  # the star, once
    assert distance[at_star[0]] < 0.1 and chi2[at_star[0]] < 16.0
    matched = distance <= 3.0
    assert np.unique(near[matched]).size == matched.sum()  # no star behind two spots
    assert np.mean(chi2[matched] <= 25.0) >= 0.98


def tumble_sample(count: int, every: int = 8) -> list:
    """`count` (FrameSource, mission, frame) of stress plans' tumbles (every `every`-th clean frame of each)."""
    sample = []
    for seed in range(3, 40):
        source = FrameSource()  # one per plan: it keeps a mission's motion by the mission's index
        for mission in plan_stress(60, seed, required=FAULT_KINDS).missions:
            if mission.motion_kind != "tumble":
                continue
            clean = [f for f in mission.frames if f.sent and not f.fault and not f.bad_info]
            sample += [(source, mission, f) for f in clean[::every]]
            if len(sample) >= count:
                return sample[:count]
    return sample


@pytest.mark.slow
def test_stress_tumble_frames_report_each_star_once():
    # Tumbles of up to 5 deg/s (streaks up to ~25 px) in every sensor condition, the exact rate
    # as the aid: no two spots of a frame coincide, and the spots on stars lie on them within
    # their covariance.
    sample = tumble_sample(20)
    assert len(sample) == 20
    within, matched = 0, 0
    for source, mission, frame in sample:
        rendered = source.render(mission, frame)
        spots = extract_spots(rendered.image, CentroidConfig(),
                              SmearModel(source.camera, rendered.truth.body_rate, EXPOSURE))
        assert closest_pair(spots) > COINCIDENT_PX, (mission.index, frame.index)
        _, distance, chi2 = truth_chi2(spots, rendered.truth)
        on_star = distance <= 3.0
        within += int(np.sum(on_star & (chi2 <= 25.0)))
        matched += int(on_star.sum())
    assert matched > 20 * 50 and within >= 0.98 * matched
