# SPDX-License-Identifier: Apache-2.0
"""
Attitude motion profiles against independent truth.

Closed forms, finite differences of the attitude, conservation laws and a separately
formulated high-accuracy integration.
"""
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation, Slerp

from star_tracker.models.attitude import (matrix_to_quaternion, matrix_to_rotation_vector, quaternion_to_matrix,
                                          radec_roll_to_matrix, rotation_vector_to_matrix, skew)
from star_tracker.sim.motion import (ConstantRateMotion, JitterMotion, SampledMotion, SlewMotion, TumbleMotion,
                                     motion_from_parameters)

R0 = radec_roll_to_matrix(1.2, -0.4, 0.7)


def angle_between(ra, rb):
    return float(np.linalg.norm(matrix_to_rotation_vector(ra.T @ rb)))


def rate_by_finite_difference(motion, t, h=1e-6):
    """Return omega from R^T dR/dt = [omega x], dR/dt by central differences."""
    r_minus, r, r_plus = motion.rotations_at(np.array([t - h, t, t + h]))
    a = r.T @ (r_plus - r_minus) / (2 * h)
    return 0.5 * np.array([a[2, 1] - a[1, 2], a[0, 2] - a[2, 0], a[1, 0] - a[0, 1]])


def assert_vectorized_matches_scalar(motion, times):
    stacked = motion.rotations_at(times)
    assert stacked.shape == (len(times), 3, 3)
    for t, r in zip(times, stacked):
        assert np.allclose(motion.rotation_at(t), r, atol=1e-15, rtol=0)


# ---------------------------------------------------------------- constant rate, fixed

def test_constant_rate_is_a_composition_of_rodrigues_rotations():
    omega, t0 = np.array([0.01, -0.02, 0.03]), 5.0
    motion = ConstantRateMotion(R0, omega, t0)
    times = np.array([t0 - 3.0, t0, t0 + 0.1, t0 + 42.0])
    expected = [R0 @ rotation_vector_to_matrix(omega * (t - t0)) for t in times]
    assert np.allclose(motion.rotations_at(times), expected, atol=1e-14, rtol=0)
    # R(t + s) = R(t) exp([omega x] s)
    assert np.allclose(motion.rotation_at(t0 + 7.5),
                       motion.rotation_at(t0 + 5.0) @ rotation_vector_to_matrix(omega * 2.5),
                       atol=1e-14, rtol=0)
    assert_vectorized_matches_scalar(motion, times)
    assert np.array_equal(motion.angular_velocity_at(123.0), omega)
    assert np.allclose(rate_by_finite_difference(motion, t0 + 1.0), omega, atol=1e-9, rtol=0)


def test_fixed_motion_holds_the_initial_attitude():
    motion = motion_from_parameters("fixed", R0, t0=2.0)
    times = np.array([-10.0, 2.0, 1e4])
    assert np.allclose(motion.rotations_at(times), R0, atol=1e-15, rtol=0)
    assert_vectorized_matches_scalar(motion, times)
    assert np.array_equal(motion.angular_velocity_at(50.0), np.zeros(3))


# ---------------------------------------------------------------- slew

SLEW_AXIS = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])


def turned(motion, t):
    """Rotation vector [rad] from the initial attitude, in the sensor frame."""
    return matrix_to_rotation_vector(motion.initial_rotation.T @ motion.rotation_at(t))


@pytest.mark.parametrize("angle", [0.6, -0.6])
def test_trapezoidal_slew_follows_its_profile(angle):
    # 0.01 rad/s^2 up to 0.05 rad/s: 5 s and 0.125 rad each ramp, so 0.35 rad of coast over 7 s.
    motion = SlewMotion(R0, SLEW_AXIS * 3.0, angle, 0.05, 0.01, t0=3.0, t_start=1.5)
    start, end, sign = 4.5, 21.5, np.sign(angle)
    assert motion.duration_s == pytest.approx(17.0, abs=1e-12)
    assert motion.peak_rate_rad_s == 0.05 and motion.end_time == pytest.approx(end, abs=1e-12)
    for t in (-100.0, 0.0, start):  # at rest before the slew
        assert np.array_equal(motion.rotation_at(t), R0)
        assert np.array_equal(motion.angular_velocity_at(t), np.zeros(3))
    final = R0 @ rotation_vector_to_matrix(SLEW_AXIS * angle)
    for t in (end, end + 1000.0):  # at rest at the final attitude after it
        assert np.allclose(motion.rotation_at(t), final, atol=1e-15, rtol=0)
        assert np.array_equal(motion.angular_velocity_at(t), np.zeros(3))
    assert np.allclose(turned(motion, end), SLEW_AXIS * angle, atol=1e-15, rtol=0)
    for dt, expected in [(2.0, 0.5 * 0.01 * 2.0**2), (5.0, 0.125), (8.5, 0.3), (17.0 - 2.0, 0.6 - 0.5 * 0.01 * 2.0**2)]:
        assert np.allclose(turned(motion, start + dt), sign * expected * SLEW_AXIS, atol=1e-14, rtol=0)
    assert np.allclose(motion.angular_velocity_at(start + 8.5), sign * 0.05 * SLEW_AXIS, atol=1e-16, rtol=0)
    assert np.allclose(motion.angular_velocity_at(start + 2.0), sign * 0.02 * SLEW_AXIS, atol=1e-16, rtol=0)
    speeds = [np.linalg.norm(motion.angular_velocity_at(t)) for t in np.linspace(0.0, 30.0, 3001)]
    assert max(speeds) == pytest.approx(0.05, abs=1e-15)
    # The rate integrates to the slew angle.
    grid = np.linspace(start, end, 20001)
    assert np.trapezoid([motion.angular_velocity_at(t) @ SLEW_AXIS for t in grid], grid) == pytest.approx(angle,
                                                                                                          abs=1e-8)


def test_triangular_slew_when_the_max_rate_is_not_reached():
    # 0.1 rad < max_rate^2 / accel = 0.25 rad: peak sqrt(angle * accel) after sqrt(angle / accel).
    motion = SlewMotion(R0, np.array([0.0, 0.0, 1.0]), 0.1, 0.05, 0.01)
    t_half = np.sqrt(10.0)
    assert motion.duration_s == pytest.approx(2 * t_half, abs=1e-12)
    assert motion.peak_rate_rad_s == pytest.approx(np.sqrt(1e-3), abs=1e-15)
    assert np.allclose(motion.angular_velocity_at(t_half), [0, 0, np.sqrt(1e-3)], atol=1e-15, rtol=0)
    assert np.allclose(turned(motion, t_half), [0, 0, 0.05], atol=1e-15, rtol=0)
    speeds = [np.linalg.norm(motion.angular_velocity_at(t)) for t in np.linspace(0.0, 10.0, 1001)]
    assert max(speeds) <= np.sqrt(1e-3) + 1e-15
    assert np.allclose(motion.rotation_at(100.0), R0 @ rotation_vector_to_matrix([0, 0, 0.1]), atol=1e-15, rtol=0)


def test_slew_rate_is_the_derivative_of_its_attitude():
    motion = SlewMotion(R0, SLEW_AXIS, -0.6, 0.05, 0.01, t0=3.0, t_start=1.5)
    times = np.concatenate([np.linspace(3.0, 23.0, 41), [4.5, 9.5, 16.5, 21.5]])  # incl. phase changes
    for t in times:
        assert np.allclose(rate_by_finite_difference(motion, t), motion.angular_velocity_at(t), atol=1e-6, rtol=0)
    assert_vectorized_matches_scalar(motion, times)


@pytest.mark.parametrize("name, value", [("axis", [0, 0, 0]), ("axis", [1, 2]), ("max_rate_rad_s", 0.0),
                                         ("accel_rad_s2", -1.0), ("angle_rad", np.nan), ("t_start", "soon"),
                                         ("initial_rotation", 2 * np.eye(3))])
def test_slew_rejects_bad_parameters(name, value):
    params = dict(initial_rotation=R0, axis=[0, 0, 1], angle_rad=0.1, max_rate_rad_s=0.05, accel_rad_s2=0.01)
    with pytest.raises(ValueError, match=name):
        SlewMotion(**{**params, name: value})


# ---------------------------------------------------------------- jitter

def jitter_theta(motion, t):
    """theta(t) and its derivative straight from the definition (independent of the class)."""
    a, f, p = motion.amplitudes_rad, motion.frequencies_hz, motion.phases_rad
    arg = 2 * np.pi * f[:, None] * (t - motion.base.t0) + p
    return np.sum(a * np.sin(arg), axis=0), np.sum(a * 2 * np.pi * f[:, None] * np.cos(arg), axis=0)


def test_jitter_rate_matches_finite_differences_at_large_amplitude():
    # Large angles make the right Jacobian J_r far from identity, so a wrong J_r would show.
    base = ConstantRateMotion(R0, np.array([0.01, -0.02, 0.005]), t0=0.5)
    motion = JitterMotion(base, [[0.2, -0.1, 0.3], [0.05, 0.15, -0.1]], [0.7, 2.3], [[0.1, 0.5, -0.3], [1.0, 2.0, 0.2]])
    for t in np.random.default_rng(1).uniform(0.0, 10.0, 25):
        omega, numeric = motion.angular_velocity_at(t), rate_by_finite_difference(motion, t)
        assert np.linalg.norm(omega - numeric) <= 1e-7 * np.linalg.norm(numeric)
        theta, theta_dot = jitter_theta(motion, t)
        naive = rotation_vector_to_matrix(theta).T @ base.body_rate + theta_dot  # J_r = I
        assert np.linalg.norm(naive - numeric) > 1e-2 * np.linalg.norm(numeric)


def test_realistic_jitter_over_a_slew_matches_finite_differences():
    base = SlewMotion(R0, SLEW_AXIS, 0.6, 0.05, 0.01, t0=3.0, t_start=1.5)
    motion = JitterMotion(base, np.array([5e-6, 3e-6, 1e-6, 1e-6, -2e-6, 4e-6]), [50.0, 120.0], [0.3, 1.1])
    for t in np.linspace(5.0, 21.0, 33):  # while slewing
        omega, numeric = motion.angular_velocity_at(t), rate_by_finite_difference(motion, t)
        assert np.linalg.norm(omega - numeric) <= 1e-7 * np.linalg.norm(numeric)


def test_jitter_is_a_zero_mean_rotation_on_top_of_the_base():
    base = ConstantRateMotion(R0, np.array([0.02, 0.01, -0.03]), t0=2.0)
    motion = JitterMotion(base, [1e-4, -2e-4, 5e-5, 3e-5, 3e-5, 1e-4], [1.0, 3.0], [0.4, 2.0, 1.0, 0.0, 0.5, 3.0])
    times = 2.0 + np.arange(0.0, 10.0, 1e-3)  # ten whole periods of both terms, uniformly sampled
    offsets = np.array([matrix_to_rotation_vector(b.T @ r)
                        for b, r in zip(base.rotations_at(times), motion.rotations_at(times))])
    assert np.allclose(offsets, [jitter_theta(motion, t)[0] for t in times], atol=1e-15, rtol=0)
    assert np.all(np.abs(offsets.mean(axis=0)) < 1e-12)
    assert_vectorized_matches_scalar(motion, times[:40])


def test_jitter_accepts_flat_and_per_term_parameters():
    base = ConstantRateMotion(R0, np.zeros(3))
    one = JitterMotion(base, [1e-5, 2e-5, 3e-5], 10.0, [0.1, 0.2, 0.3])  # one term, per-axis phases
    assert one.amplitudes_rad.shape == (1, 3) and np.array_equal(one.phases_rad, [[0.1, 0.2, 0.3]])
    three = JitterMotion(base, np.ones((3, 3)) * 1e-5, [1.0, 2.0, 3.0], [0.1, 0.2, 0.3])  # three terms, per term
    assert np.array_equal(three.phases_rad, np.repeat([[0.1], [0.2], [0.3]], 3, axis=1))


@pytest.mark.parametrize("kwargs, name", [
    (dict(amplitudes_rad=[1e-5, 1e-5], frequencies_hz=[10.0]), "amplitudes_rad"),
    (dict(amplitudes_rad=np.ones((3, 2)), frequencies_hz=[10.0, 20.0]), "amplitudes_rad"),
    (dict(amplitudes_rad=[1e-5] * 3, frequencies_hz=[10.0, 20.0]), "frequencies_hz"),
    (dict(amplitudes_rad=[1e-5] * 3, frequencies_hz=[-1.0]), "frequencies_hz"),
    (dict(amplitudes_rad=[1e-5] * 6, frequencies_hz=[1.0, 2.0], phases_rad=[0.0] * 4), "phases_rad"),
])
def test_jitter_rejects_bad_parameters(kwargs, name):
    with pytest.raises(ValueError, match=name):
        JitterMotion(ConstantRateMotion(R0, np.zeros(3)), **kwargs)
    with pytest.raises(ValueError, match="base"):
        JitterMotion(R0, [1e-5] * 3, [1.0])


# ---------------------------------------------------------------- tumble

INERTIA = np.array([10.0, 15.0, 22.0])


def rigid_body_reference(rotation, omega0, inertia, t0, times):
    """Independent solution: 3x3 matrix + body rate, DOP853 at rtol 1e-13, at the exact times."""
    def rhs(_t, y):
        r, w = y[:9].reshape(3, 3), y[9:]
        return np.concatenate([(r @ skew(w)).ravel(), np.cross(inertia * w, w) / inertia])

    y0 = np.concatenate([rotation.ravel(), omega0])
    out = {}
    for side in (times[times >= t0], times[times < t0]):
        ordered = np.sort(side) if np.all(side >= t0) else np.sort(side)[::-1]
        if ordered.size:
            sol = solve_ivp(rhs, (t0, ordered[-1]), y0, method="DOP853", t_eval=ordered, rtol=1e-13, atol=1e-15)
            out.update({t: (y[:9].reshape(3, 3), y[9:]) for t, y in zip(ordered, sol.y.T)})
    return [out[t] for t in times]


@pytest.mark.parametrize("omega0", [[0.3, -0.2, 0.25], [0.01, 0.5, 0.01]], ids=["generic", "intermediate-axis"])
def test_tumble_conserves_energy_and_inertial_angular_momentum(omega0):
    motion = TumbleMotion(R0, omega0, INERTIA)
    times = np.linspace(0.0, 100.0, 1001)
    rotations = np.concatenate([motion.rotations_at(chunk) for chunk in np.array_split(times, 25)])
    rates = np.array([motion.angular_velocity_at(t) for t in times])
    energy = 0.5 * np.sum(INERTIA * rates**2, axis=1)
    momentum = np.einsum("kij,kj->ki", rotations, INERTIA * rates)
    energy0, momentum0 = 0.5 * INERTIA @ np.square(omega0), R0 @ (INERTIA * omega0)
    assert np.max(np.abs(energy / energy0 - 1)) < 1e-9
    assert np.max(np.linalg.norm(momentum - momentum0, axis=1)) < 1e-9 * np.linalg.norm(momentum0)
    if omega0[1] == 0.5:  # the unstable intermediate axis flips over within 100 s: a demanding case
        assert rates[:, 1].min() < -0.4


def test_axisymmetric_tumble_matches_the_closed_form():
    # I1 = I2 = I: Euler gives dw1/dt = -lam w2, dw2/dt = lam w1 with lam = (I3 - I) / I * w3, so the
    # transverse rate turns about +z at lam. With L the (inertial, constant) angular momentum,
    # omega = R^T L / I - lam z, whence R(t) = exp([L x] t / I) R0 exp(-[z x] lam t).
    inertia, omega0 = np.array([4.0, 4.0, 7.0]), np.array([0.2, 0.1, 0.5])
    lam = (7.0 - 4.0) / 4.0 * 0.5
    motion = TumbleMotion(R0, omega0, inertia, t0=3.0)
    momentum = R0 @ (inertia * omega0)
    for t in np.random.default_rng(2).uniform(-17.0, 103.0, 40):
        tau = t - 3.0
        c, s = np.cos(lam * tau), np.sin(lam * tau)
        assert np.allclose(motion.angular_velocity_at(t), [c * 0.2 - s * 0.1, s * 0.2 + c * 0.1, 0.5], atol=1e-11,
                           rtol=0)
        expected = rotation_vector_to_matrix(momentum * tau / 4.0) @ R0 @ rotation_vector_to_matrix([0, 0, -lam * tau])
        assert angle_between(motion.rotation_at(t), expected) < 1e-9


def test_tumble_matches_an_independent_integration_at_arbitrary_times():
    rotation, omega0, t0 = R0.T, np.array([0.4, -0.3, 0.6]), 7.0
    motion = TumbleMotion(rotation, omega0, INERTIA, t0=t0)
    times = np.random.default_rng(3).uniform(t0 - 20.0, t0 + 100.0, 60)  # random order: the cache grows both ways
    for t, (r_ref, w_ref) in zip(times, rigid_body_reference(rotation, omega0, INERTIA, t0, times)):
        assert angle_between(motion.rotation_at(t), r_ref) < 1e-9
        assert np.linalg.norm(motion.angular_velocity_at(t) - w_ref) < 1e-9 * np.linalg.norm(omega0)
    assert_vectorized_matches_scalar(motion, np.linspace(t0 + 50.0, t0 + 50.1, 40))
    assert np.allclose(motion.rotation_at(t0), rotation, atol=1e-15, rtol=0)
    assert np.allclose(motion.angular_velocity_at(t0), omega0, atol=1e-17, rtol=0)


def test_tumble_rejects_bad_parameters_and_far_times():
    with pytest.raises(ValueError, match="inertia_kg_m2"):
        TumbleMotion(R0, [0, 0, 0.1], [1.0, 1.0, 3.0])  # no rigid body has I3 > I1 + I2
    with pytest.raises(ValueError, match="inertia_kg_m2"):
        TumbleMotion(R0, [0, 0, 0.1], [1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="initial_rate_rad_s"):
        TumbleMotion(R0, [0, 0.1], INERTIA)
    with pytest.raises(ValueError, match="initial_rotation"):
        TumbleMotion(R0 * 1.01, [0, 0, 0.1], INERTIA)
    with pytest.raises(ValueError, match="max_span_s"):  # epoch time against a simulation-time t0
        TumbleMotion(R0, [0, 0, 0.1], INERTIA).rotation_at(1.7e9)


# ---------------------------------------------------------------- sampled

OMEGA = np.array([0.3, -0.2, 0.4])


def constant_rate_samples(times, flip_signs=True):
    truth = ConstantRateMotion(R0, OMEGA, t0=times[0])
    quats = np.array([matrix_to_quaternion(r) for r in truth.rotations_at(times)])
    if flip_signs:  # q and -q are the same attitude; interpolation must not care
        quats[1::2] *= -1
    return truth, quats


def sample_times(n=30, seed=4):
    return 100.0 + np.cumsum(np.random.default_rng(seed).uniform(0.05, 0.5, n))


def test_sampled_interpolation_is_exact_for_constant_rate_motion():
    times = sample_times()
    truth, quats = constant_rate_samples(times)
    motion = SampledMotion(times, quats)
    assert np.allclose(motion.rotations_at(times), [quaternion_to_matrix(q) for q in quats], atol=1e-15, rtol=0)
    queries = np.concatenate([times, np.random.default_rng(5).uniform(times[0], times[-1], 200)])
    assert np.allclose(motion.rotations_at(queries), truth.rotations_at(queries), atol=1e-13, rtol=0)
    for t in queries[::20]:
        assert np.allclose(motion.angular_velocity_at(t), OMEGA, atol=1e-12, rtol=0)
    assert_vectorized_matches_scalar(motion, queries[:40])


def test_sampled_interpolation_is_slerp():
    times = sample_times(seed=6)
    rotations = Rotation.from_rotvec(np.random.default_rng(7).normal(0.0, 0.3, (30, 3))).as_matrix()  # steps < pi
    quats = np.array([matrix_to_quaternion(r) for r in rotations])
    motion = SampledMotion(times, quats)
    queries = np.random.default_rng(8).uniform(times[0], times[-1], 200)
    expected = Slerp(times, Rotation.from_matrix(rotations))(queries).as_matrix()
    assert np.allclose(motion.rotations_at(queries), expected, atol=1e-13, rtol=0)


@pytest.mark.parametrize("with_rates", [False, True])
def test_sampled_extrapolates_with_the_last_rate_up_to_the_limit(with_rates):
    times = sample_times()
    truth, quats = constant_rate_samples(times)
    motion = SampledMotion(times, quats, np.tile(OMEGA, (len(times), 1)) if with_rates else None,
                           max_extrapolation_s=0.5)
    ahead = times[-1] + np.array([0.0, 0.1, 0.25, 0.5])
    assert np.allclose(motion.rotations_at(ahead), truth.rotations_at(ahead), atol=1e-13, rtol=0)
    assert np.allclose(motion.angular_velocity_at(ahead[-1]), OMEGA, atol=1e-12, rtol=0)
    with pytest.raises(ValueError, match="max_extrapolation_s"):
        motion.rotations_at(np.array([times[-1], times[-1] + 0.5 + 1e-6]))
    with pytest.raises(ValueError, match="max_extrapolation_s"):
        motion.angular_velocity_at(times[-1] + 0.6)
    with pytest.raises(ValueError, match="before the first sample"):
        motion.rotation_at(times[0] - 1e-6)


def test_sampled_uses_the_supplied_rates():
    times = np.array([0.0, 1.0, 2.0])
    quats = np.array([matrix_to_quaternion(R0)] * 3)
    rates = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.2, 0.0]])
    motion = SampledMotion(times, quats, rates)
    assert np.allclose(motion.angular_velocity_at(1.25), [0.075, 0.05, 0.0], atol=1e-16, rtol=0)  # linear
    assert np.allclose(motion.rotation_at(2.5), R0 @ rotation_vector_to_matrix([0.0, 0.1, 0.0]), atol=1e-15, rtol=0)
    single = SampledMotion([5.0], [matrix_to_quaternion(R0)])  # one sample, no rate: holds still
    assert np.allclose(single.rotations_at(np.array([5.0, 6.0])), R0, atol=1e-15, rtol=0)
    assert np.array_equal(single.angular_velocity_at(5.5), np.zeros(3))


def test_sampled_append_streams_samples():
    times = sample_times(n=40)
    _, quats = constant_rate_samples(times)
    rates = np.tile(OMEGA, (len(times), 1))
    batch = SampledMotion(times, quats, rates)
    stream = SampledMotion(times[:2], quats[:2], rates[:2])
    for t, q, w in zip(times[2:], quats[2:], rates[2:]):  # grows past the initial buffer
        stream.append(t, q, w)
    assert np.array_equal(stream.times, times)
    queries = np.linspace(times[0], times[-1] + 1.0, 300)
    assert np.allclose(stream.rotations_at(queries), batch.rotations_at(queries), atol=1e-15, rtol=0)
    for bad_time in (times[-1], times[-1] - 1.0):
        with pytest.raises(ValueError, match="after the last sample"):
            stream.append(bad_time, quats[0], OMEGA)
    with pytest.raises(ValueError, match="rate"):
        stream.append(times[-1] + 1.0, quats[0])
    with pytest.raises(ValueError, match="rate"):
        SampledMotion(times, quats).append(times[-1] + 1.0, quats[0], OMEGA)
    with pytest.raises(ValueError):  # the exposed arrays are read-only views
        stream.times[0] = 0.0
    assert np.array_equal(stream.times, times)


@pytest.mark.parametrize("kwargs, name", [
    (dict(times=[0.0, 1.0, 1.0], quaternions=np.tile([0, 0, 0, 1.0], (3, 1))), "times"),
    (dict(times=[0.0, 1.0], quaternions=[[0, 0, 0, 1.0]]), "quaternions"),
    (dict(times=[0.0, 1.0], quaternions=[[0, 0, 0, 1.0], [0, 0, 0, 0]]), "quaternions"),
    (dict(times=[0.0, 1.0], quaternions=np.tile([0, 0, 0, 1.0], (2, 1)), rates=np.zeros((2, 2))), "rates"),
    (dict(times=[0.0], quaternions=[[0, 0, 0, 1.0]], max_extrapolation_s=-1.0), "max_extrapolation_s"),
])
def test_sampled_rejects_bad_samples(kwargs, name):
    with pytest.raises(ValueError, match=name):
        SampledMotion(**kwargs)


# ---------------------------------------------------------------- factory

def test_factory_builds_each_kind_from_plain_values():
    rate = [0.01, 0.02, -0.01]
    constant = motion_from_parameters("constant_rate", R0, body_rate_rad_s=rate, t0=1)
    assert np.allclose(constant.rotation_at(11.0), R0 @ rotation_vector_to_matrix(np.multiply(rate, 10.0)),
                       atol=1e-15, rtol=0)
    slew = motion_from_parameters("slew", R0, axis=[0, 0, 2], angle_rad=0.2, max_rate_rad_s=0.05,
                                  accel_rad_s2=0.01, t0=1.0, t_start=2)
    assert isinstance(slew, SlewMotion)
    assert np.allclose(slew.rotation_at(100.0), R0 @ rotation_vector_to_matrix([0, 0, 0.2]), atol=1e-15, rtol=0)
    tumble = motion_from_parameters("tumble", R0, initial_rate_rad_s=[0.1, 0, 0.2], inertia_kg_m2=[1, 2, 2.5])
    assert isinstance(tumble, TumbleMotion) and np.allclose(tumble.angular_velocity_at(0.0), [0.1, 0, 0.2])
    jitter = motion_from_parameters("jitter", R0, body_rate_rad_s=rate, amplitudes_rad=[1e-5, 0, 0, 0, 2e-5, 0],
                                    frequencies_hz=[10, 20], phases_rad=[0.0, 1.0], t0=1.0)
    assert isinstance(jitter, JitterMotion) and jitter.amplitudes_rad.shape == (2, 3)
    theta = jitter_theta(jitter, 1.3)[0]
    assert np.allclose(jitter.rotation_at(1.3), constant.rotation_at(1.3) @ rotation_vector_to_matrix(theta),
                       atol=1e-15, rtol=0)


@pytest.mark.parametrize("kind, kwargs, message", [
    ("spin", {}, "unknown motion kind 'spin'"),
    ("constant_rate", {}, r"missing parameter.*body_rate_rad_s"),
    ("fixed", {"body_rate_rad_s": [0, 0, 0]}, r"unknown parameter.*body_rate_rad_s"),
    ("fixed", {"t0": float("nan")}, "t0 must be finite"),
    ("constant_rate", {"body_rate_rad_s": [0.1, 0.2]}, "body_rate_rad_s must have shape"),
    ("constant_rate", {"body_rate_rad_s": ["fast", 0, 0]}, "body_rate_rad_s must be numeric"),
    ("slew", dict(axis=[0, 0, 1], angle_rad=0.2, max_rate_rad_s=-1, accel_rad_s2=0.01), "max_rate_rad_s must be > 0"),
    ("tumble", dict(initial_rate_rad_s=[0, 0, 0.1], inertia_kg_m2=[1, 1, 3]), "inertia_kg_m2"),
    ("jitter", dict(amplitudes_rad=[1e-5] * 4, frequencies_hz=[10]), "amplitudes_rad"),
    ("jitter", dict(amplitudes_rad=[1e-5] * 3, frequencies_hz=[10, 20]), "frequencies_hz"),
])
def test_factory_rejects_bad_input_with_a_clear_message(kind, kwargs, message):
    with pytest.raises(ValueError, match=message):
        motion_from_parameters(kind, R0, **kwargs)
    with pytest.raises(ValueError, match="initial_rotation"):
        motion_from_parameters("fixed", [[1, 0], [0, 1]])
