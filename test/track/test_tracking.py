# SPDX-License-Identifier: Apache-2.0
"""
Tracking (localized recognition), rate estimate, forced loss and delay compensation, against the simulator's truth.

Real renderer, real centroider, real database.
"""
import math

import numpy as np
import pytest

from star_tracker.models.attitude import attitude_error, radec_roll_to_matrix, rotation_vector_to_matrix
from star_tracker.centroid import CentroidConfig, Spots, extract_spots
from star_tracker.identify import make_identifier
from star_tracker.track.tracking import (MODE_LOST, MODE_LOST_IN_SPACE, MODE_TRACKING, Prediction, Tracker,
                                         TrackingConfig, log_chance_tuples_in_region)
from star_tracker.identify.verify import log_chance_tuples
from star_tracker.sim.motion import ConstantRateMotion, SlewMotion
from star_tracker.track.rate import AttitudeRateEstimator
from star_tracker.sim.render import StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel

ARCSEC = math.pi / 180 / 3600
PERIOD_S = 0.1


@pytest.fixture(scope="module")
def tracker_parts(catalog, database, nominal_camera):
    lis = make_identifier("hybrid", database)
    tracker = Tracker(lis)
    tracker.warm_up(nominal_camera)
    renderer = StarFieldRenderer(nominal_camera, SensorModel(), catalog, magnitude_limit=7.5)
    return lis, tracker, renderer


def frames_of(renderer, motion, count, first=0, seed=0):
    """(stamp_ns, frame) at 10 Hz: mid-exposure stamps 0.05 s + k * 0.1 s."""
    for k in range(first, first + count):
        t = 0.05 + PERIOD_S * k
        yield int(round(t * 1e9)), renderer.render(motion, t, frame_seed(seed, k))


def centroid(frame, camera, tracker=None, stamp_ns=None):
    """Return the centroider, rate-aided by the tracker's own estimate as in the node pipeline."""
    smear = None if tracker is None else tracker.centroider_aid(stamp_ns, camera, 0.1)
    return extract_spots(frame.image, CentroidConfig(), smear)


def true_hip(frame, spots, radius=2.0):
    """HIP id of the star nearest each spot (0 when none within `radius` px)."""
    truth = frame.truth
    stars = np.flatnonzero(truth.stars())
    d = np.hypot(spots.x[:, None] - truth.x[stars][None], spots.y[:, None] - truth.y[stars][None])
    nearest = d.argmin(axis=1)
    return np.where(d[np.arange(len(spots)), nearest] <= radius, truth.hip[stars][nearest], 0)


def assert_correct(result, frame, spots, cross_arcsec=5.0, roll_arcsec=20.0):
    ident = result.identification
    assert ident.solved, ident.reason
    # 3 px: the deep re-match also names faint streaks, whose centroids can sit ~2 px from their star.
    assert np.array_equal(ident.hip, true_hip(frame, spots, radius=3.0)[ident.spot_index])
    cross, roll, _ = attitude_error(ident.attitude.rotation, frame.truth.rotation)
    assert cross < cross_arcsec * ARCSEC and roll < roll_arcsec * ARCSEC, (cross / ARCSEC, roll / ARCSEC)


def test_slew_is_tracked_on_every_frame_with_an_honest_rate(tracker_parts, nominal_camera):
    lis, _, renderer = tracker_parts
    # The rate's model error assumes |d omega/dt| <= the slew's 2 deg/s^2.
    tracker = Tracker(lis, TrackingConfig(max_angular_acceleration_rad_s2=np.radians(2.0)))
    # 2 deg/s cross-boresight at the top of the slew: stars smear ~14 px in the 0.1 s exposure.
    motion = SlewMotion(radec_roll_to_matrix(1.4, 0.35, 0.2), axis=np.array([0.6, 0.8, 0.0]), angle_rad=np.radians(3.0),
                        max_rate_rad_s=np.radians(2.0), accel_rad_s2=np.radians(2.0), t_start=0.3)
    modes, normalized = [], []
    for stamp_ns, frame in frames_of(renderer, motion, 30):
        spots = centroid(frame, nominal_camera, tracker, stamp_ns)
        result = tracker.process(stamp_ns, spots, nominal_camera)
        # Acceleration inside the exposure moves a streak's centroid off the mid-exposure
        # position by ~alpha T^2 / 24 (3" here), which the constant-rate smear model ignores.
        assert_correct(result, frame, spots, cross_arcsec=8.0)
        modes.append(result.mode)
        if result.rate is not None:
            normalized.append((result.rate.angular_velocity - frame.truth.body_rate) / result.rate.sigma)
    assert modes[0] == MODE_LOST_IN_SPACE and set(modes[1:]) == {MODE_TRACKING}
    normalized = np.array(normalized)
    assert len(normalized) >= 28
    # Honest sigma: errors of its size (RMS ~1 per axis); an acceleration step inside the
    # window that the chi^2 test misses may bias one estimate by a few sigma.
    assert np.all(np.sqrt(np.mean(normalized**2, axis=0)) < 2.0), np.sqrt(np.mean(normalized**2, axis=0))
    assert np.mean(np.abs(normalized) > 4.0) < 0.03 and np.abs(normalized).max() < 8.0, np.abs(normalized).max(axis=0)


def test_constant_rate_estimate_is_consistent(tracker_parts, nominal_camera):
    """Without acceleration the rate's stated sigma is the GLS one: errors of its size, not far smaller."""
    lis, _, renderer = tracker_parts
    tracker = Tracker(lis, TrackingConfig(max_angular_acceleration_rad_s2=0.0))
    true_rate = np.radians([0.4, -0.3, 0.8])
    motion = ConstantRateMotion(radec_roll_to_matrix(3.0, -0.6, 1.0), true_rate)
    nees = []
    for stamp_ns, frame in frames_of(renderer, motion, 30, seed=3):
        result = tracker.process(stamp_ns, centroid(frame, nominal_camera, tracker, stamp_ns), nominal_camera)
        assert result.solved
        if result.rate is not None and result.rate.frames >= 3:
            err = result.rate.angular_velocity - true_rate
            nees.append(err @ np.linalg.solve(result.rate.covariance, err))
    # Successive estimates share attitudes, so the mean is noisy: a loose window around 3.
    assert 0.5 < np.mean(nees) < 9.0, np.mean(nees)


def test_forced_loss_reacquires_on_the_next_frame(tracker_parts, nominal_camera):
    _, tracker, renderer = tracker_parts
    tracker.reset()
    motion = ConstantRateMotion(radec_roll_to_matrix(5.0, 0.9, -0.4), np.radians([0.5, 0.2, 0.1]))
    for k, (stamp_ns, frame) in enumerate(frames_of(renderer, motion, 8, seed=5)):
        spots = centroid(frame, nominal_camera, tracker, stamp_ns)
        if k == 4:  # a blinded frame (Sun or Earth in the field): no spots at all
            result = tracker.process(stamp_ns, Spots.empty(nominal_camera.width, nominal_camera.height), nominal_camera)
            assert result.mode == MODE_LOST and not result.solved
            continue
        result = tracker.process(stamp_ns, spots, nominal_camera)
        assert_correct(result, frame, spots)
        if k == 5:
            assert result.mode == MODE_TRACKING  # re-acquired from the prediction across the gap


def test_wrong_prediction_never_gives_a_wrong_attitude(tracker_parts, nominal_camera):
    _, tracker, renderer = tracker_parts
    motion = ConstantRateMotion(radec_roll_to_matrix(2.0, 0.1, 0.3), np.zeros(3))
    (stamp_ns, frame), = frames_of(renderer, motion, 1, seed=7)
    spots = centroid(frame, nominal_camera)
    for offset_deg in (0.3, 1.0, 3.0):  # prediction off by more than its own gate claims
        wrong = frame.truth.rotation @ rotation_vector_to_matrix(np.radians([offset_deg, -offset_deg,
                                                                             0.5 * offset_deg]))
        prediction = Prediction(stamp_ns, wrong, np.eye(3) * (20 * ARCSEC) ** 2)
        result, _ = tracker.track(spots, nominal_camera, prediction)
        assert not result.solved, result.reason


def test_three_stars_track_but_do_not_solve_lost_in_space(tracker_parts, nominal_camera):
    lis, tracker, renderer = tracker_parts
    motion = ConstantRateMotion(radec_roll_to_matrix(4.0, -0.2, 0.0), np.zeros(3))
    (stamp_ns, frame), = frames_of(renderer, motion, 1, seed=11)
    spots = centroid(frame, nominal_camera)
    hip = true_hip(frame, spots)
    real = np.flatnonzero(np.isin(hip, lis.database.hip))  # guide stars only
    # Three well-separated real stars, as after an occultation of most of the field.
    x, y = spots.x[real], spots.y[real]
    pick = [int(np.argmin(x + y)), int(np.argmax(x - y)), int(np.argmax(y - 0.2 * x))]
    three = spots.take(real[pick])
    assert len(set(pick)) == 3
    assert not lis.identify(three, nominal_camera).solved
    prediction = Prediction(stamp_ns, frame.truth.rotation @ rotation_vector_to_matrix(np.full(3, 5 * ARCSEC)),
                            np.eye(3) * (30 * ARCSEC) ** 2)
    result, _ = tracker.track(three, nominal_camera, prediction)
    assert result.solved, result.reason
    assert np.array_equal(result.hip, hip[real[pick]][result.spot_index])
    # Random spots in the same place are never verified.
    rng = np.random.default_rng(0)
    for _ in range(20):
        fake = Spots(rng.uniform(0, 1023, 8), rng.uniform(0, 1023, 8), np.full(8, 1e4), np.full(8, 50.0),
                     np.tile(np.eye(2) * 0.01, (8, 1, 1)), np.zeros(8, np.uint32), np.full(8, 9, np.int32),
                     np.full(8, 1e3), 1024, 1024)
        assert not tracker.track(fake, nominal_camera, prediction)[0].solved


def test_delay_compensation_publishes_the_newest_frame(tracker_parts, nominal_camera):
    lis, tracker, renderer = tracker_parts
    tracker.reset()
    motion = ConstantRateMotion(radec_roll_to_matrix(0.7, 0.5, 2.0), np.radians([1.5, -1.0, 0.5]))
    frames = list(frames_of(renderer, motion, 6, seed=13))
    spots = [centroid(frame, nominal_camera) for _, frame in frames]
    tracker.begin_acquisition(frames[0][0], spots[0], nominal_camera)
    for (stamp_ns, _), frame_spots in zip(frames[1:], spots[1:]):  # arrive while the solve runs
        assert tracker.bridge(stamp_ns, frame_spots, nominal_camera)
    result = tracker.complete_acquisition(lis.identify(spots[0], nominal_camera))
    assert result is not None and result.bridged_frames == 5 and result.stamp_ns == frames[-1][0]
    assert_correct(result, frames[-1][1], spots[-1])


def test_region_bound_reduces_to_the_lost_in_space_bound(nominal_camera):
    rng = np.random.default_rng(2)
    body = rng.normal(size=(5, 3)) * [0.05, 0.05, 0.0] + [0, 0, 1]
    body /= np.linalg.norm(body, axis=1, keepdims=True)
    sigma = np.full(5, 5e-5)
    whole = log_chance_tuples(body, sigma, 4.0, 200.0)
    assert log_chance_tuples_in_region(body, sigma, 4.0, 200.0, np.eye(3) * 10.0, 5.0) == pytest.approx(whole)
    small = log_chance_tuples_in_region(body, sigma, 4.0, 200.0, np.eye(3) * (1e-4) ** 2, 5.0)
    smaller = log_chance_tuples_in_region(body, sigma, 4.0, 200.0, np.eye(3) * (1e-5) ** 2, 5.0)
    assert smaller < small < whole


def test_rate_estimator_gls_matches_its_covariance():
    rng = np.random.default_rng(4)
    omega = np.radians([1.0, -2.0, 0.5])
    start = radec_roll_to_matrix(1.0, 0.2, 0.3)
    cov = np.diag([(1 * ARCSEC) ** 2, (1 * ARCSEC) ** 2, (10 * ARCSEC) ** 2])
    nees = []
    for trial in range(400):
        estimator = AttitudeRateEstimator(window_s=0.35, max_angular_acceleration_rad_s2=0.0)
        estimate = None
        for k in range(4):
            t = 0.1 * k
            noise = rng.multivariate_normal(np.zeros(3), cov)
            rotation = start @ rotation_vector_to_matrix(omega * t) @ rotation_vector_to_matrix(noise)
            estimate = estimator.add(int(t * 1e9), rotation, cov)
        err = estimate.angular_velocity - omega
        nees.append(err @ np.linalg.solve(estimate.covariance, err))
    assert 2.6 < np.mean(nees) < 3.4


def test_rate_window_restarts_after_a_rate_step():
    """
    A rate step before the newest attitude breaks the window's model.

    The fit falls back to the newest two attitudes, whose constant-rate slope (with the lag
    term) covers the truth.
    """
    rng = np.random.default_rng(5)
    start = radec_roll_to_matrix(0.4, -0.3, 1.0)
    cov = np.diag([(1 * ARCSEC) ** 2, (1 * ARCSEC) ** 2, (6 * ARCSEC) ** 2])
    before, after = np.radians([0.5, 0.0, 0.0]), np.radians([0.5, 1.0, 0.0])
    alpha_max = np.radians(20.0)  # the step happens within 0.05 s: |d omega/dt| = 20 deg/s^2
    estimator = AttitudeRateEstimator(window_s=0.6, max_angular_acceleration_rad_s2=alpha_max)
    for k in range(6):
        t = 0.1 * k
        rotation = start @ rotation_vector_to_matrix(before * t)
        if k == 5:  # the rate changed at t = 0.45
            rotation = start @ rotation_vector_to_matrix(before * 0.45) @ rotation_vector_to_matrix(after * 0.05)
        estimate = estimator.add(int(t * 1e9), rotation @ rotation_vector_to_matrix(
            rng.multivariate_normal(np.zeros(3), cov)), cov)
        if k == 4:
            assert estimate.frames == 5
            assert np.all(np.abs(estimate.angular_velocity - before) < 4 * estimate.sigma)
    assert estimate.frames == 2
    # The two-frame slope is the mean rate of the last interval; the truth is `after`.
    assert np.all(np.abs(estimate.angular_velocity - after) < 3 * estimate.sigma)
