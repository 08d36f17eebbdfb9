# SPDX-License-Identifier: Apache-2.0
"""
Angular acceleration within the exposure, against the simulator's truth.

The rate estimate's acceleration, the smear model's accelerated path, the published covariance.

Real renderer, real centroider, real database.
"""
import math

import numpy as np
import pytest

from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid.streak.smear import SmearModel
from star_tracker.identify import make_identifier
from star_tracker.models.attitude import (matrix_to_rotation_vector, quaternion_to_matrix, radec_roll_to_matrix,
                                          rotation_vector_to_matrix)
from star_tracker.sim.motion import SlewMotion
from star_tracker.sim.render import StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel
from star_tracker.track.rate import ACCELERATION_MAX_AGE_S, AttitudeRateEstimator
from star_tracker.track.tracking import Tracker

ARCSEC = math.pi / 180 / 3600
EXPOSURE_S = 0.1
ALPHA = math.radians(2.0)  # [rad/s^2]
NEES_997 = 13.93  # chi^2_3(0.997)
NEES_5_SIGMA = 31.8  # chi^2_3 at the two-sided 5-sigma probability


def aid(tracker, stamp_ns, camera):
    """Return the smear model a rate-aided centroider gets: the tracker's rate and acceleration at the frame."""
    return tracker.centroider_aid(stamp_ns, camera, EXPOSURE_S)


def test_rate_estimate_carries_the_acceleration():
    axis = np.array([0.6, -0.79, 0.1]) / np.linalg.norm([0.6, -0.79, 0.1])
    omega0, alpha = np.radians(0.5) * axis, np.radians(1.5) * axis  # eigen-axis: phi(t) is exact
    sigma = 0.5 * ARCSEC
    start = radec_roll_to_matrix(0.3, 0.2, 0.1)
    nees = {4: [], 5: []}
    for seed in range(100):
        rng = np.random.default_rng(seed)
        rates = AttitudeRateEstimator(0.45, ALPHA)
        for k in range(5):
            t = 0.1 * k
            truth = start @ rotation_vector_to_matrix(omega0 * t + 0.5 * alpha * t * t)
            measured = truth @ rotation_vector_to_matrix(rng.normal(0.0, sigma, 3))
            estimate = rates.add(int(round(t * 1e9)), measured, np.eye(3) * sigma ** 2)
            if k < 3:  # fewer than four attitudes: no tested fit, no acceleration
                assert estimate is None or estimate.angular_acceleration is None
                continue
            if estimate.angular_acceleration is None:  # the fit failed its 1 % test: none published
                continue
            error = estimate.angular_acceleration - alpha
            nees[k + 1].append(error @ np.linalg.solve(estimate.acceleration_covariance, error))
        # The rate at the newest frame, carried one frame on by the acceleration.
        if estimate.angular_acceleration is not None:
            omega_next, _ = estimate.at(int(round(0.5 * 1e9)))
            assert np.linalg.norm(omega_next - (omega0 + alpha * 0.5)) < np.radians(0.02), np.degrees(omega_next)
    # Its covariance is its error's: NEES mean 3 (100 draws: 3 +- 0.5 at 2 sigma).
    for frames, values in nees.items():
        assert len(values) >= 95, (frames, len(values))
        assert 2.3 < np.mean(values) < 4.0, (frames, np.mean(values))


def test_jitter_publishes_no_acceleration():
    # 20" of jitter at 7 Hz about every axis, seen at 10 Hz with 0.2" noise: no window of four
    # attitudes fits a constant acceleration, so none is published. The newest three's exact
    # quadratic (the jitter's aliased curvature, ~0.2 deg/s^2 here) would move a rate-aided
    # frame's spots by alpha T^2 / 24 ~ 0.4", twice the attitude's stated sigma, every frame.
    from star_tracker.sim.motion import ConstantRateMotion, JitterMotion

    sigma = 0.2 * ARCSEC
    start = radec_roll_to_matrix(0.3, 0.2, 0.1)
    motion = JitterMotion(ConstantRateMotion(start, np.radians([0.1, 0.0, 0.0])), np.full((1, 3), 20.0 * ARCSEC),
                          [7.0], [0.0, 1.0, 2.0])
    rng = np.random.default_rng(3)
    rates = AttitudeRateEstimator(0.45, ALPHA)
    times = 0.1 * np.arange(60)
    published, curvature = 0, []
    for t, truth in zip(times, motion.rotations_at(times)):
        measured = truth @ rotation_vector_to_matrix(rng.normal(0.0, sigma, 3))
        estimate = rates.add(int(round(t * 1e9)), measured, np.eye(3) * sigma ** 2)
        if estimate is not None and estimate.angular_acceleration is not None:
            published += 1
        if t >= 0.2:  # what the newest three's exact quadratic says: the second difference
            phi = [matrix_to_rotation_vector(start.T @ r) for r in motion.rotations_at([t - 0.2, t - 0.1, t])]
            curvature.append(np.linalg.norm(phi[0] - 2 * phi[1] + phi[2]) / 0.01)
    assert np.median(curvature) * EXPOSURE_S ** 2 / 24 > 2 * sigma, np.median(curvature)
    assert published == 0, published


def ramp_estimates(bias_gain_s2):
    """
    Feed a rate estimator a ramp's attitudes as a rate-aided centroider measures them; return each estimate.

    Rest, then 2 deg/s^2 from t = 0.45 s. Each frame's attitude is the exposure average where the
    acceleration its aid had (the previous estimate's) missed the body's: g (alpha - A) off the
    mid-exposure one, g = T^2 / 24 (point-like spots), plus 0.2" of noise.
    """
    axis = np.array([0.6, 0.8, 0.0])
    alpha = ALPHA * axis
    gain = EXPOSURE_S ** 2 / 24
    sigma = 0.2 * ARCSEC
    start = radec_roll_to_matrix(0.3, 0.2, 0.1)
    rng = np.random.default_rng(11)
    rates = AttitudeRateEstimator(0.45, ALPHA)
    estimates, applied = [], None
    for k in range(14):
        t = 0.05 + 0.1 * k
        ramp = max(t - 0.45, 0.0)
        truth = start @ rotation_vector_to_matrix(0.5 * alpha * ramp * ramp)
        missed = (alpha if t > 0.45 else np.zeros(3)) - (np.zeros(3) if applied is None else applied)
        measured = truth @ rotation_vector_to_matrix(gain * missed + rng.normal(0.0, sigma, 3))
        estimate = rates.add(int(round(t * 1e9)), measured, np.eye(3) * sigma ** 2, bias_gain_s2, applied)
        estimates.append((t, estimate))
        applied = None if estimate is None else estimate.angular_acceleration
    return alpha, estimates


def test_a_ramp_measured_with_and_without_its_acceleration_is_one_motion():
    # The first ramp frames are measured without the acceleration (none estimated yet), the
    # later ones with it: 3" apart. Told each frame's bias gain, the estimator fits one motion
    # and holds the acceleration from the fourth ramp frame on; without it, the window breaks.
    alpha, estimates = ramp_estimates(EXPOSURE_S ** 2 / 24)
    held = [e for t, e in estimates if t > 0.45 + 0.35]
    assert all(e.angular_acceleration is not None for e in held), [e.frames for e in held]
    for e in held:
        error = e.angular_acceleration - alpha
        assert error @ np.linalg.solve(e.acceleration_covariance, error) < 16.3, error  # chi^2_3, 0.1 %
    _, bare = ramp_estimates(0.0)
    assert sum(e.angular_acceleration is None for t, e in bare if t > 0.45 + 0.35) >= 2


def test_smear_model_exposure_mean_offset_is_alpha_t2_over_24(nominal_camera):
    smear = SmearModel(nominal_camera, np.zeros(3), EXPOSURE_S, np.array([0.0, ALPHA, 0.0]))
    offset = smear.exposure_mean_offset([nominal_camera.cx], [nominal_camera.cy])[0]
    expected = ALPHA * EXPOSURE_S ** 2 / 24 / nominal_camera.pixel_scale_rad
    assert abs(abs(offset[0]) - expected) < 0.01 * expected and abs(offset[1]) < 1e-6 * expected, offset
    # The path is the accelerated one: zero at mid-exposure, uneven in time.
    path = smear.path([nominal_camera.cx], [nominal_camera.cy], samples=5)[0]
    assert np.allclose(path[2], 0.0) and abs(np.mean(path[:, 0])) > 0.5 * expected


@pytest.fixture(scope="module")
def parts(catalog, database, nominal_camera):
    lis = make_identifier("hybrid", database)
    Tracker(lis).warm_up(nominal_camera)
    renderer = StarFieldRenderer(nominal_camera, SensorModel(), catalog, magnitude_limit=7.5)
    return lis, renderer


def slew():
    """Rest 0.5 s, 2 deg/s^2 to 1.5 deg/s (0.75 s), coast: a slew across the boresight with a little roll."""
    return SlewMotion(radec_roll_to_matrix(1.4, 0.35, 0.2), axis=np.array([0.6, 0.8, 0.1]), angle_rad=np.radians(20.0),
                      max_rate_rad_s=np.radians(1.5), accel_rad_s2=ALPHA, t_start=0.5)


def test_an_accelerated_frame_is_measured_at_mid_exposure(parts, nominal_camera):
    _, renderer = parts
    motion = slew()
    t = 1.05  # 0.55 s into the ramp: 1.1 deg/s, stars smeared ~9 px
    frame = renderer.render(motion, t, frame_seed(4, 0))
    omega = frame.truth.body_rate
    alpha = (motion.angular_velocity_at(t + 1e-3) - motion.angular_velocity_at(t - 1e-3)) / 2e-3
    stars = np.flatnonzero(frame.truth.stars())
    along = omega[[1, 0]] * [-1.0, 1.0]  # image motion of the boresight under (wx, wy): (-wy, wx) up to sign
    bias = {}
    for name, smear in (("constant rate", SmearModel(nominal_camera, omega, EXPOSURE_S)),
                        ("accelerated", SmearModel(nominal_camera, omega, EXPOSURE_S, alpha))):
        spots = extract_spots(frame.image, CentroidConfig(), smear)
        assert np.array_equal(spots.applied_motion.angular_velocity_rad_s, omega)  # what the tracker is told
        assert (spots.applied_motion.angular_acceleration_rad_s2 is None) == (name == "constant rate")
        bright = np.argsort(-spots.flux)[:30]
        d = np.hypot(spots.x[bright, None] - frame.truth.x[stars], spots.y[bright, None] - frame.truth.y[stars])
        near = d.min(axis=1) < 2.0
        offsets = np.column_stack([spots.x[bright] - frame.truth.x[stars][d.argmin(axis=1)],
                                   spots.y[bright] - frame.truth.y[stars][d.argmin(axis=1)]])[near]
        assert near.sum() >= 15
        bias[name] = np.median(offsets, axis=0)
    scale = np.linalg.norm(alpha) * EXPOSURE_S ** 2 / 24 / nominal_camera.pixel_scale_rad  # alpha T^2 / 24 [px]
    # With the constant-rate path the streaks lean toward the slow end by more than alpha T^2 / 24;
    # on the accelerated path they sit at mid-exposure.
    assert np.linalg.norm(bias["constant rate"]) > 0.8 * scale, (bias, scale, along)
    assert np.linalg.norm(bias["accelerated"]) < 0.25 * scale, (bias, scale)


def track_slew(parts, camera, smear_for):
    """
    Track the slew's 22 frames, each centroided with smear_for(tracker, estimates, stamp_ns).

    estimates: the tracker's rate estimate after each earlier frame. Returns per frame the NEES
    of the published attitude, its error (sensor frame) [rad] and the smear model applied.
    """
    lis, renderer = parts
    motion = slew()
    tracker = Tracker(lis)
    estimates, nees, errors, smears = [], [], [], []
    for k in range(22):
        t = 0.05 + 0.1 * k
        stamp_ns = int(round(t * 1e9))
        frame = renderer.render(motion, t, frame_seed(5, k))
        smear = smear_for(tracker, estimates, stamp_ns)
        spots = extract_spots(frame.image, CentroidConfig(), smear)
        result = tracker.process(stamp_ns, spots, camera)
        ident = result.identification
        assert ident.solved, (k, ident.reason)
        estimates.append(tracker.rate)
        error = matrix_to_rotation_vector(frame.truth.rotation.T @ ident.attitude.rotation)
        nees.append(float(error @ np.linalg.solve(ident.attitude.covariance, error)))
        errors.append(error)
        smears.append(smear)
    return np.array(nees), errors, smears


def test_an_accelerating_slew_is_published_with_an_honest_covariance(parts, nominal_camera):
    motion = slew()
    nees, errors, smears = track_slew(parts, nominal_camera,
                                      lambda tracker, estimates, stamp_ns: aid(tracker, stamp_ns, nominal_camera))
    ramp_errors = []
    for k, (error, smear) in enumerate(zip(errors, smears)):
        t = 0.05 + 0.1 * k
        change = motion.angular_velocity_at(t + 0.05) - motion.angular_velocity_at(t - 0.05)
        if np.linalg.norm(change) > 1e-9 and smear is not None and smear.angular_acceleration_rad_s2 is not None:
            ramp_errors.append(error)
    # The mean of a consistent covariance is 3; no frame beyond 5 sigma, at most one beyond the
    # 99.7 % ellipsoid (the frame whose exposure the ramp's end cuts, a step the innovation
    # sees only in part).
    assert nees.max() < NEES_5_SIGMA and np.sum(nees > NEES_997) <= 1, np.round(nees, 1)
    assert 1.5 < nees.mean() < 4.5, np.round(nees, 1)
    # The exposure-average bias (alpha T^2 / 24 = 3", more for streaks on a constant-rate path) is removed.
    assert len(ramp_errors) >= 2
    assert np.linalg.norm(np.mean(ramp_errors, axis=0)[:2]) < 0.3 * ALPHA * EXPOSURE_S ** 2 / 24, \
        np.mean(ramp_errors, axis=0) / ARCSEC


def test_a_slew_aided_frames_late_is_published_with_an_honest_covariance_when_the_spots_say_so(parts, nominal_camera):
    # The centroider's aid is the tracker's estimate two frames old (what the identifier's input
    # age on a loaded host gives, bench_slew_nodes): that estimate's rate carried to the frame by
    # its acceleration, the acceleration while no older than ACCELERATION_MAX_AGE_S. The spots
    # say what they were measured with (Spots.applied_motion, the centroider's smear_aid); were
    # the tracker to assume its newest estimate was applied, the frame after the ramp's start
    # would be published ~12 sigma off (NEES 138 on this slew; mean 8.7).
    lag_frames = 2

    def late(tracker, estimates, stamp_ns):
        rate = estimates[-1 - lag_frames] if len(estimates) > lag_frames else None
        if rate is None:  # no estimate yet (a track's first frames)
            return None
        omega, alpha = rate.at(stamp_ns)
        fresh = rate.angular_acceleration is not None and stamp_ns - rate.stamp_ns <= ACCELERATION_MAX_AGE_S * 1e9
        return SmearModel(nominal_camera, omega, EXPOSURE_S, alpha if fresh else None)

    nees, _, _ = track_slew(parts, nominal_camera, late)
    assert nees.max() < NEES_5_SIGMA and np.sum(nees > NEES_997) <= 1, np.round(nees, 1)
    assert 1.5 < nees.mean() < 4.5, np.round(nees, 1)


def solution(rotation, sigma_rad):
    """Return a solved Identification with `rotation` and an isotropic covariance (no stars: the state only)."""
    from star_tracker.identify.base import Identification
    from star_tracker.models.attitude import matrix_to_quaternion
    from star_tracker.models.attitude_estimation import AttitudeSolution
    return Identification("solved", "synthetic", "tracking", 0.0,
                          attitude=AttitudeSolution(matrix_to_quaternion(rotation), rotation,
                                                    np.eye(3) * sigma_rad ** 2, 0.0))


def accept_path(tracker, times, angle_of):
    """Feed the tracker noiseless attitudes rotating about +X by angle_of(t); return each published covariance."""
    base = radec_roll_to_matrix(1.4, 0.35, 0.2)
    out = []
    for t in times:
        rotation = base @ rotation_vector_to_matrix(np.array([angle_of(t), 0.0, 0.0]))
        frame = tracker._accept(int(round(t * 1e9)), solution(rotation, ARCSEC), "tracking", None, 0, 0.0)
        out.append(frame.identification.attitude.covariance)
    return out


def test_the_added_covariance_is_what_the_acceleration_can_do_to_one_exposure(parts):
    lis, _ = parts
    alpha_max = math.radians(2.0)
    gain = EXPOSURE_S ** 2 / 24
    bound = (gain * alpha_max) ** 2 / 3  # uniform within +-alpha_max per axis [rad^2]
    # 10 Hz at rest, then 1 deg/s^2 about +X from t = 0.95 s (a step the rate estimate did not know).
    accel = math.radians(1.0)
    times = 0.1 * np.arange(16)
    angle = lambda t: 0.5 * accel * max(t - 0.95, 0.0) ** 2  # noqa: E731
    added = [c - np.eye(3) * ARCSEC ** 2 for c in accept_path(Tracker(lis), times, angle)]
    # First three frames: no acceleration known (none tested): the bound. From the fourth on, at
    # rest, the estimate that includes the frame says ~0: next to nothing added.
    assert all(np.allclose(a, np.eye(3) * bound) for a in added[:3])
    assert all(np.max(np.diag(a)) < 0.01 * bound for a in added[3:11])
    # The step shows in frame 11 (0.15 s into the slew; frame 10's exposure saw 0.05 s of it):
    # along X, about (alpha_max T^2 / 24)^2 / 3 (the least acceleration change explaining an
    # innovation of alpha (0.15 s)^2 / 2 = 40" over 0.1 s is 2.05 deg/s^2), not the innovation's
    # 40"^2 / 3 (3,000x more).
    step = added[11]
    assert 0.5 * bound < step[0, 0] < (gain * math.radians(2.1)) ** 2 / 3
    assert step[1, 1] < 0.01 * step[0, 0] and step[2, 2] < 0.01 * step[0, 0]
    # Frame 12: the estimate after it tests a window with the step inside and fails; the one
    # including frame 13 (four attitudes on the ramp) passes. The centroider had no acceleration
    # for frame 12, and the one it missed (1 deg/s^2 along X) is what is added, then nothing.
    assert 0.5 < added[12][0, 0] / (gain * accel) ** 2 < 1.5, added[12][0, 0] / (gain * accel) ** 2
    assert all(np.max(np.diag(a)) < 0.01 * bound for a in added[13:])
    # A frame 0.6 s after the last (frames lost): the aid's estimate is stale (ACCELERATION_MAX_AGE_S),
    # the window holds one attitude: the bound.
    tracker = Tracker(lis)
    accept_path(tracker, times[:6], angle)
    gap = accept_path(tracker, [times[5] + 0.6], angle)[0] - np.eye(3) * ARCSEC ** 2
    assert np.allclose(gap, np.eye(3) * bound)


def test_a_frame_fitted_on_a_gyros_path_is_carried_to_mid_exposure_by_its_offset(parts):
    # Under jitter on a steady drift, each frame's spots measure the exposure-average attitude
    # of a path the gyro drew: the tracker publishes it carried to mid-exposure by the path's
    # offset, with the offset's covariance and no acceleration terms (it knows the path), and
    # its rate window sees the mid-exposure attitudes (the drift, not the jitter).
    from star_tracker.centroid.applied_motion import AppliedMotion

    lis, _ = parts
    base = radec_roll_to_matrix(1.4, 0.35, 0.2)
    omega = np.array([0.0, math.radians(0.3), 0.0])
    offset_cov = np.eye(3) * (0.2 * ARCSEC) ** 2
    tracker = Tracker(lis)
    for k in range(8):
        t = 0.1 * k
        mid = base @ rotation_vector_to_matrix(omega * t)
        offset = np.array([30.0 * math.sin(2.0 + 7.0 * k), 20.0 * math.cos(1.0 + 5.0 * k), 0.0]) * ARCSEC
        mean = mid @ rotation_vector_to_matrix(offset).T  # R_mid = R_mean exp([offset x])
        frame = tracker._accept(int(round(t * 1e9)), solution(mean, ARCSEC), "tracking", None, 0, 0.0, None,
                                AppliedMotion(omega, None, offset, offset_cov))
        published = frame.identification.attitude
        assert np.allclose(published.rotation, mid, atol=1e-12)
        assert np.allclose(quaternion_to_matrix(published.quaternion), mid, atol=1e-12)
        assert np.allclose(published.covariance, np.eye(3) * ARCSEC ** 2 + offset_cov)
    assert np.allclose(frame.rate.angular_velocity, omega, atol=1e-9)


def test_the_bias_gain_covers_a_constant_rate_fit_of_an_accelerated_streak(parts, nominal_camera):
    lis, renderer = parts
    motion = slew()
    t = 1.2  # 0.7 s into the 2 deg/s^2 ramp: 1.4 deg/s, streaks of ~10 px
    frame = renderer.render(motion, t, frame_seed(6, 0))
    omega = frame.truth.body_rate
    alpha = (motion.angular_velocity_at(t + 1e-3) - motion.angular_velocity_at(t - 1e-3)) / 2e-3
    spots = extract_spots(frame.image, CentroidConfig(), SmearModel(nominal_camera, omega, EXPOSURE_S))
    stars = np.flatnonzero(frame.truth.stars())
    bright = np.argsort(-spots.flux)[:30]
    d = np.hypot(spots.x[bright, None] - frame.truth.x[stars], spots.y[bright, None] - frame.truth.y[stars])
    near = d.min(axis=1) < 3.0
    offsets = np.column_stack([spots.x[bright] - frame.truth.x[stars][d.argmin(axis=1)],
                               spots.y[bright] - frame.truth.y[stars][d.argmin(axis=1)]])[near]
    assert near.sum() >= 15
    measured = np.linalg.norm(np.median(offsets, axis=0)) * nominal_camera.pixel_scale_rad  # [rad]
    modelled = Tracker(lis).bias_gain(omega, nominal_camera.pixel_scale_rad) * np.linalg.norm(alpha)
    # More than the point-like alpha T^2 / 24, and the model covers it without doubling it.
    assert measured > 1.2 * np.linalg.norm(alpha) * EXPOSURE_S ** 2 / 24, (measured, modelled)
    assert 0.6 * modelled < measured < 1.1 * modelled, (measured / ARCSEC, modelled / ARCSEC)
