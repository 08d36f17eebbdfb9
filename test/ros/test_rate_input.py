# SPDX-License-Identifier: Apache-2.0
"""
The centroider's rate inputs (rate_input.py) and the QoS helper (qos.py), with real message classes and no ROS graph.

Rotation into the sensor frame, the frame/stamp/REP 145 checks and their counters, the choice
of the sample for a frame.
"""
import numpy as np
import pytest

from geometry_msgs.msg import Vector3Stamped
from sensor_msgs.msg import Imu

from star_tracker.models.attitude import matrix_to_quaternion, quaternion_to_matrix
from star_tracker.ros import convert
from star_tracker.ros.qos import RATE_INPUT_QOS, SPOTS_QOS, is_qos_override, overridable
from star_tracker.centroid.streak.exposure_path import ExposurePath
from star_tracker.ros.rate_input import RateInput, RateSamples, mounting_matrix

T0 = 1_700_000_000 * 10**9
MS = 10**6
# Gyro mounted rotated 90 deg about the sensor's +Z: its +X is the sensor's +Y.
MOUNT_Z90 = [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)]


class Counted:
    def __init__(self):
        self.counts, self.texts = {}, []

    def __call__(self, counter, text):
        self.counts[counter] = self.counts.get(counter, 0) + 1
        self.texts.append(text)


def imu(omega, stamp_ns, frame="imu_link", covariance0=0.0):
    msg = Imu()
    msg.header.stamp = convert.ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = (float(v) for v in omega)
    msg.angular_velocity_covariance[0] = covariance0
    return msg


def vector3(omega, stamp_ns, frame="star_tracker_optical") -> Vector3Stamped:
    return convert.vector3_msg(np.asarray(omega, float), stamp_ns, frame)


def test_imu_rate_is_rotated_into_the_sensor_frame():
    reject = Counted()
    rates = RateInput(reject, MOUNT_Z90, "imu_link")
    rates.on_imu(imu([0.01, 0.0, 0.0], T0))
    omega = rates.for_frame("imu", T0, 0.1, 0.5)
    assert np.allclose(omega, [0.0, 0.01, 0.0], atol=1e-15)
    assert reject.counts == {}
    # Any mounting: v_sensor = R(q) v_gyro, the convention of every quaternion in this package.
    q = np.array([0.3, -0.2, 0.5, 0.78])
    q /= np.linalg.norm(q)
    rates = RateInput(reject, q)
    rates.on_imu(imu([0.01, -0.02, 0.03], T0))
    assert np.allclose(rates.for_frame("imu", T0, 0.1, 0.5), quaternion_to_matrix(q) @ [0.01, -0.02, 0.03])


def test_vector3_is_sensor_frame_unless_in_the_gyro_frame():
    reject = Counted()
    rates = RateInput(reject, MOUNT_Z90, "imu_link")
    rates.on_vector3(vector3([0.01, 0.0, 0.0], T0))  # the identifier's own estimate: as is
    assert np.allclose(rates.for_frame("angular_velocity", T0, 0.1, 0.5), [0.01, 0.0, 0.0])
    rates.on_vector3(vector3([0.01, 0.0, 0.0], T0 + 200 * MS, "imu_link"))  # a gyro remapped: rotated
    assert np.allclose(rates.for_frame("angular_velocity", T0 + 200 * MS, 0.1, 0.5), [0.0, 0.01, 0.0])
    assert reject.counts == {}


def test_bad_rate_messages_are_counted_and_ignored():
    reject = Counted()
    rates = RateInput(reject, gyro_frame_id="imu_link")
    rates.on_imu(imu([0.01, 0, 0], T0, frame="base_link"))
    rates.on_imu(imu([0.01, 0, 0], T0, covariance0=-1.0))  # REP 145: no angular velocity
    rates.on_imu(imu([np.nan, 0, 0], T0))
    rates.on_imu(imu([0.01, 0, 0], 0))  # unstamped
    rates.on_vector3(vector3([np.inf, 0, 0], T0))
    assert reject.counts == {"rates_wrong_frame": 1, "rates_no_data": 1, "rates_rejected": 3}
    assert "base_link" in reject.texts[0] and "non-finite values" in reject.texts[2]
    assert len(rates.samples["imu"]) == 0 and len(rates.samples["angular_velocity"]) == 0
    # An all-zero covariance means "unknown" (REP 145): used.
    rates.on_imu(imu([0.01, 0, 0], T0))
    assert rates.for_frame("imu", T0, 0.1, 0.5) is not None


def test_frames_without_a_recent_rate_are_counted():
    reject = Counted()
    rates = RateInput(reject)
    assert rates.for_frame("imu", T0, 0.1, 0.5) is None
    rates.on_imu(imu([0.01, 0, 0], T0))
    assert rates.for_frame("imu", T0 + 600 * MS, 0.1, 0.5) is None  # 0.6 s > max_rate_age_s
    assert rates.for_frame("imu", T0 - 600 * MS, 0.1, 0.5) is None  # from the future as well
    assert rates.for_frame("imu", T0 + 400 * MS, 0.1, 0.5) is not None
    assert rates.for_frame("angular_velocity", T0, 0.1, 0.5) is None  # the other input has nothing
    assert reject.counts == {"frames_without_rate": 2, "frames_rate_too_old": 2}


def test_clear_forgets_the_samples_and_keeps_the_mounting():
    reject = Counted()
    rates = RateInput(reject, MOUNT_Z90, "imu_link")
    rates.on_imu(imu([0.01, 0.0, 0.0], T0))
    rates.clear()  # lifecycle cleanup
    assert rates.for_frame("imu", T0, 0.1, 0.5) is None
    assert reject.counts == {"frames_without_rate": 1}
    rates.on_imu(imu([0.01, 0.0, 0.0], T0))
    assert np.allclose(rates.for_frame("imu", T0, 0.1, 0.5), [0.0, 0.01, 0.0], atol=1e-15)


def test_the_frame_gets_the_mean_rate_of_its_exposure_else_the_nearest_sample():
    samples = RateSamples()
    for k in range(-100, 101):  # a 1 kHz gyro, rate ramping in x by 0.001 rad/s per ms
        samples.add(T0 + k * MS, np.array([0.001 * k, 0.0, 0.0]))
    omega, verdict = samples.for_frame(T0 + 10 * MS, 0.02, 0.5)  # exposure: the 21 samples 0..20 ms
    assert verdict == "ok" and omega[0] == pytest.approx(0.010)
    omega, verdict = samples.for_frame(T0 + 300 * MS, 0.02, 0.5)  # none inside: the nearest, at 100 ms
    assert verdict == "ok" and omega[0] == pytest.approx(0.100)
    assert samples.for_frame(T0 + 300 * MS, 0.02, 0.1)[1] == "too_old"


def test_the_frame_gets_the_acceleration_of_the_newest_samples():
    alpha = np.array([0.02, -0.01, 0.005])  # [rad/s^2]
    omega0 = np.array([0.01, 0.02, 0.0])
    # The identifier's estimates at 10 Hz, the newest stamped 100 ms before the frame (a frame late).
    estimates = RateSamples()
    for k in range(-5, 0):
        estimates.add(T0 + k * 100 * MS, omega0 + alpha * k * 0.1)
    omega, acceleration, verdict = estimates.motion_for_frame(T0, 0.1, 0.5)
    assert verdict == "ok" and np.allclose(acceleration, alpha) and np.allclose(omega, omega0)  # carried to T0
    # A 1 kHz gyro: the mean rate inside the exposure, the slope of the last 0.25 s.
    gyro = RateSamples()
    for k in range(-300, 51):
        gyro.add(T0 + k * MS, omega0 + alpha * k * 1e-3)
    omega, acceleration, verdict = gyro.motion_for_frame(T0, 0.1, 0.5)
    assert np.allclose(acceleration, alpha) and np.allclose(omega, omega0)
    # One sample: a rate, no acceleration.
    single = RateSamples()
    single.add(T0 - 100 * MS, omega0)
    omega, acceleration, verdict = single.motion_for_frame(T0, 0.1, 0.5)
    assert acceleration is None and np.allclose(omega, omega0)


def test_the_identifiers_acceleration_carries_its_newest_rate():
    # The identifier's rate and acceleration, stamped alike, the newest 100 ms before the frame:
    # the frame gets that acceleration and the rate carried by it (RateEstimate.at), not the
    # slope of successive rates (which lags a step).
    counted = Counted()
    rates = RateInput(counted)
    omega0 = np.array([0.03, 0.0, 0.0])
    for k in range(-4, 0):
        rates.on_vector3(vector3(omega0, T0 + k * 100 * MS))  # constant so far: a slope of zero
    accel = vector3([-0.02, 0.0, 0.0], T0 - 100 * MS)
    rates.on_acceleration(accel)
    omega, alpha = rates.motion_for_frame("angular_velocity", T0, 0.1, 0.5)
    assert np.allclose(alpha, [-0.02, 0.0, 0.0]) and np.allclose(omega, omega0 + np.array([-0.002, 0.0, 0.0]))
    # A newer rate without its acceleration (the identifier had none: a new track): none.
    rates.on_vector3(vector3(omega0, T0 - 50 * MS))
    assert rates.motion_for_frame("angular_velocity", T0, 0.1, 0.5)[1] is None
    # Bad acceleration messages are counted and ignored.
    rates.on_acceleration(vector3([np.nan, 0.0, 0.0], T0))
    rates.on_acceleration(vector3([0.0, 0.0, 0.0], 0))
    assert counted.counts == {"rates_rejected": 2}


def test_stale_samples_give_no_acceleration():
    # A slew braking at 0.02 rad/s^2, seen by the identifier's estimates until 0.6 s before the
    # frame (frames dropped since): their slope would carry the braking into a frame after the stop.
    alpha = np.array([-0.02, 0.0, 0.0])
    omega0 = np.array([0.03, 0.0, 0.0])
    samples = RateSamples()
    for k in range(-9, -5):
        samples.add(T0 + k * 100 * MS, omega0 + alpha * k * 0.1)
    omega, acceleration, verdict = samples.motion_for_frame(T0, 0.1, 1.0)
    assert verdict == "ok" and acceleration is None and np.allclose(omega, omega0 + alpha * -0.6)  # newest sample
    # The same samples 0.5 s before the frame (ACCELERATION_MAX_AGE_S): still the slope.
    omega, acceleration, verdict = samples.motion_for_frame(T0 - 100 * MS, 0.1, 1.0)
    assert np.allclose(acceleration, alpha)


def test_samples_kept_are_bounded_and_forgotten_when_time_restarts():
    samples = RateSamples(kept=10)
    for k in range(100):
        samples.add(T0 + k * MS, np.zeros(3))
    assert len(samples) == 10
    samples.add(T0 + 50 * MS, np.ones(3))  # out of order by 49 ms: kept with the others
    assert len(samples) == 10
    samples.add(T0 - 5 * 10**9, np.ones(3))  # 5 s back: a replay restarted
    assert len(samples) == 1 and samples.for_frame(T0 + 99 * MS, 0.1, 0.5)[1] == "too_old"


@pytest.mark.parametrize("quaternion, problem", [
    ([0.0, 0.0, 0.0], "4 finite values"), ([0.0, 0.0, np.nan, 1.0], "4 finite values"),
    ([0.0, 0.0, 0.0, 2.0], "unit norm"), ([0.0, 0.0, 0.0, 0.0], "unit norm")])
def test_bad_mounting_is_refused(quaternion, problem):
    with pytest.raises(ValueError, match=problem):
        mounting_matrix(quaternion)
    with pytest.raises(ValueError, match="gyro.mounting_quaternion"):
        RateInput(Counted(), quaternion)


def test_mounting_typed_to_four_decimals_is_accepted():
    matrix = mounting_matrix([0.0, 0.0, 0.7071, 0.7071])
    assert np.allclose(matrix @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    assert np.allclose(matrix_to_quaternion(matrix), MOUNT_Z90)


def test_overridable_copies_the_profile():
    kwargs = overridable(SPOTS_QOS)
    assert kwargs["qos_profile"] == SPOTS_QOS and kwargs["qos_profile"] is not SPOTS_QOS
    kwargs["qos_profile"].depth = 1  # rclpy writes the overrides into it: the shared profile is untouched
    assert SPOTS_QOS.depth == 20 and RATE_INPUT_QOS.reliability.name == "BEST_EFFORT"
    assert is_qos_override("qos_overrides./imu.subscription.reliability") and not is_qos_override("rate_source")


def test_a_gyros_slope_under_fast_jitter_is_no_acceleration():
    # 20" of jitter at 20 Hz seen by a 1 kHz gyro: the rate swings by 0.7 deg/s, its 0.25 s slope
    # is the swings' artefact, not the body's acceleration (track/aid_acceleration.py).
    amplitude, frequency = np.radians(20.0 / 3600.0), 20.0
    gyro = RateSamples()
    for k in range(-300, 51):
        t = k * 1e-3
        gyro.add(T0 + k * MS, np.array([1.0, -0.5, 0.2]) * amplitude * 2 * np.pi * frequency
                 * np.cos(2 * np.pi * frequency * t + 0.4))
    omega, acceleration, verdict = gyro.motion_for_frame(T0, 0.1, 0.5)
    assert verdict == "ok" and acceleration is None and omega is not None


def test_a_slope_needs_two_exposures_of_samples():
    # A gyro switched on (or a new track's first samples): one exposure of samples cannot tell a
    # 2-10 Hz jitter's swing from an acceleration (ACCELERATION_MIN_SPAN_S), two can.
    alpha = np.array([0.02, -0.01, 0.005])  # [rad/s^2]
    omega0 = np.array([0.01, 0.02, 0.0])
    for first_ms, expected in ((-50, None), (-120, None), (-150, alpha)):  # to +50 ms: 0.1, 0.17, 0.2 s
        gyro = RateSamples()
        for k in range(first_ms, 51):
            gyro.add(T0 + k * MS, omega0 + alpha * k * 1e-3)
        omega, acceleration, verdict = gyro.motion_for_frame(T0, 0.1, 0.5)
        assert verdict == "ok" and np.allclose(omega, omega0), first_ms
        assert (acceleration is None) if expected is None else np.allclose(acceleration, expected), first_ms


def test_a_gyros_samples_around_the_exposure_draw_its_path():
    # The samples within an exposure's length of either end, relative to the frame's stamp; the
    # identifier's estimates (they come with accelerations) draw none.

    amplitude, frequency = np.radians(20.0 / 3600.0), 10.0
    gyro = RateSamples()
    for k in range(-300, 151, 10):  # a 100 Hz gyro
        t = k * 1e-3
        gyro.add(T0 + k * MS, np.array([amplitude * 2 * np.pi * frequency * np.cos(2 * np.pi * frequency * t), 0.0,
                                        0.0]))
    offsets, rates, noise = gyro.around_exposure(T0, 0.1)
    assert offsets.min() == pytest.approx(-0.15) and offsets.max() == pytest.approx(0.15) and noise == 0.0
    path = ExposurePath.from_rate_samples(offsets, rates, 0.1)
    # phi_x(t) = A sin(2 pi f t), its exposure mean zero (a whole period): the path's swing,
    # within 0.5 % (a cubic spline through 10 samples per period).
    probe = np.array([-0.025, 0.0, 0.025])
    assert np.allclose(path.at(probe)[:, 0], amplitude * np.sin(2 * np.pi * frequency * probe), atol=0.005 * amplitude)
    estimates = RateSamples()
    for k in range(-300, 151, 10):
        estimates.add(T0 + k * MS, np.zeros(3))
        estimates.add_acceleration(T0 + k * MS, np.zeros(3))
    assert estimates.around_exposure(T0, 0.1) is None
    assert RateSamples().around_exposure(T0, 0.1) is None


def test_an_imus_stated_noise_comes_with_its_samples_around_the_exposure():
    # The largest variance on angular_velocity_covariance's diagonal, as 1 sigma [rad/s]; all
    # zeros (REP 145: not stated) and a Vector3Stamped state none.
    counted = Counted()
    rates = RateInput(counted)
    for k in range(-5, 6):
        msg = imu([0.0, 0.01, 0.0], T0 + k * 10 * MS)
        msg.angular_velocity_covariance[4] = (1e-4 if k else 4e-4) ** 2
        rates.on_imu(msg)
    offsets, _, noise = rates.around_exposure("imu", T0, 0.1)
    assert offsets.size == 11 and noise == pytest.approx(4e-4)
    plain = RateInput(counted)
    for k in range(-5, 6):
        plain.on_imu(imu([0.0, 0.01, 0.0], T0 + k * 10 * MS))
        plain.on_vector3(vector3([0.0, 0.01, 0.0], T0 + k * 10 * MS))
    assert plain.around_exposure("imu", T0, 0.1)[2] == 0.0
    assert plain.around_exposure("angular_velocity", T0, 0.1)[2] == 0.0


def test_the_configured_gyro_noise_stands_for_messages_that_state_none():
    # gyro.noise_rad_s: a Vector3Stamped states no noise, nor does an Imu whose covariance is all
    # zeros (REP 145: not known); an Imu that states its noise keeps its own.
    counted = Counted()
    rates = RateInput(counted, gyro_noise_rad_s=2e-4)
    for k in range(-5, 6):
        rates.on_vector3(vector3([0.0, 0.01, 0.0], T0 + k * 10 * MS))
        rates.on_imu(imu([0.0, 0.01, 0.0], T0 + k * 10 * MS))
    assert rates.around_exposure("angular_velocity", T0, 0.1)[2] == pytest.approx(2e-4)
    assert rates.around_exposure("imu", T0, 0.1)[2] == pytest.approx(2e-4)
    stated = RateInput(counted, gyro_noise_rad_s=2e-4)
    for k in range(-5, 6):
        stated.on_imu(imu([0.0, 0.01, 0.0], T0 + k * 10 * MS, covariance0=(5e-5) ** 2))
    assert stated.around_exposure("imu", T0, 0.1)[2] == pytest.approx(5e-5)
    # The noise reaches the covariance of the path's offset to mid-exposure (white noise through
    # the integration): larger with it than without, by the exact propagation's scale.
    offsets, samples, noise = rates.around_exposure("angular_velocity", T0, 0.1)
    swing = samples + np.outer(np.sin(2 * np.pi * 15.0 * offsets), [1e-3, 0.0, 0.0])
    quiet = ExposurePath.from_rate_samples(offsets, swing, 0.1).mid_exposure_offset_covariance
    noisy = ExposurePath.from_rate_samples(offsets, swing, 0.1, noise).mid_exposure_offset_covariance
    added = np.diag(noisy - quiet)
    assert np.all(added > 0.0) and np.allclose(added, added[0]), added
