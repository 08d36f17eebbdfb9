# SPDX-License-Identifier: Apache-2.0
"""
QUEST cross-checked against Markley's SVD and Davenport's q-method, and its covariance.

The QUEST measurement-model covariance against the Monte-Carlo scatter of QUEST
estimates.

Geometries: "sphere" = directions anywhere on the sky (generic Wahba problem); "fov" =
directions inside the default camera's field (a 15 deg x 15 deg square, half-diagonal
10.6 deg), where two stars are close and the eigenvalue gap of Davenport's K matrix is small.
Noise model (QUEST's): each body vector gets 2-D Gaussian noise of 1-sigma sigma_i [rad]
per axis in its tangent plane.
"""
import numpy as np
import pytest

from star_tracker.models.attitude import matrix_to_rotation_vector, rotation_vector_to_matrix
from star_tracker.models.attitude_estimation import attitude_covariance, davenport_q_method, quest, svd_attitude
from star_tracker.models.camera import CameraModel

SOLVERS = (quest, svd_attitude, davenport_q_method)
CAMERA = CameraModel.from_fov(1024, 1024, np.radians(15.0))
PIXEL = CAMERA.pixel_scale_rad  # [rad/px]


def angle_between(rot_a: np.ndarray, rot_b: np.ndarray) -> float:
    """Rotation angle of R_a^T R_b [rad]."""
    return float(np.linalg.norm(matrix_to_rotation_vector(rot_a.T @ rot_b)))


def random_axis(rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    return axis / np.linalg.norm(axis)


def random_rotation(rng: np.random.Generator, kind: str) -> np.ndarray:
    """
    'any': random axis, angle uniform in [0, pi).

    'pi': exactly pi about a random or a coordinate axis (QUEST's singularity); 'near_pi':
    pi - 10^(-12..-3) rad.
    """
    if kind == "any":
        angle = rng.uniform(0.0, np.pi)
    elif kind == "pi":
        angle = np.pi
    else:
        angle = np.pi - 10.0 ** rng.uniform(-12.0, -3.0)
    axis = np.eye(3)[rng.integers(3)] if kind == "pi" and rng.random() < 0.5 else random_axis(rng)
    return rotation_vector_to_matrix(angle * axis)


def body_directions(rng: np.random.Generator, n: int, geometry: str) -> np.ndarray:
    """(n, 3) sensor-frame unit vectors: anywhere ('sphere') or in the camera's field ('fov')."""
    if geometry == "sphere":
        v = rng.normal(size=(n, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)
    return CAMERA.pixel_to_ray(rng.uniform(0, CAMERA.width - 1, n), rng.uniform(0, CAMERA.height - 1, n))


def noisy(rng: np.random.Generator, body: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """Body vectors with QUEST's noise model: sigma per axis in each tangent plane."""
    e1 = np.cross(body, np.where(np.abs(body[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(body, e1)
    n1, n2 = rng.normal(size=(2, body.shape[0])) * sigmas
    out = body + n1[:, None] * e1 + n2[:, None] * e2
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def sigmas_with_ratio(rng: np.random.Generator, n: int, ratio: float, smallest: float = 1e-5) -> np.ndarray:
    """Per-star 1-sigma [rad], log-uniform over [smallest, ratio * smallest], both ends used."""
    s = smallest * ratio ** rng.uniform(0.0, 1.0, n)
    s[0], s[-1] = smallest, smallest * ratio
    return s


def worst_clean_disagreement(seed: int, counts, geometry: str, ratio: float, kinds=("any", "pi", "near_pi"),
                             trials_per_count: int = 12) -> float:
    """
    Return the largest angle [rad] between any solver and the truth on noise-free data.

    Hence also between solvers; over star counts `counts` and rotation kinds.
    """
    rng = np.random.default_rng(seed)
    worst = 0.0
    for n in counts:
        for k in range(trials_per_count):
            truth = random_rotation(rng, kinds[k % len(kinds)])
            body = body_directions(rng, n, geometry)
            ref = body @ truth.T  # v_icrs = R v_sensor
            sigmas = sigmas_with_ratio(rng, n, ratio)
            for solver in SOLVERS:
                worst = max(worst, angle_between(solver(body, ref, sigmas).rotation, truth))
    return worst


@pytest.mark.parametrize("geometry", ["sphere", "fov"])
def test_solvers_agree_on_clean_data_for_random_and_half_turn_attitudes(geometry):
    # Nearly equal weights (sigma ratio 2), 2..50 stars, a third of the attitudes exactly pi
    # and a third within 1e-3..1e-12 rad of pi (QUEST's sequential rotations at work).
    assert worst_clean_disagreement(1, range(2, 51), geometry, ratio=2.0) < 1e-9


@pytest.mark.parametrize("geometry, counts", [("sphere", range(2, 51)), ("fov", range(3, 51))])
def test_solvers_agree_on_clean_data_with_very_unequal_weights(geometry, counts):
    # Sigma ratio 30 (weights 900:1), more than the pipeline's spots span (0.05 px floor to
    # ~0.5 px). Two stars in the field are the exception: see the two-star tests below.
    assert worst_clean_disagreement(2, counts, geometry, ratio=30.0) < 1e-9


def mahalanobis(rot_a: np.ndarray, rot_b: np.ndarray, covariance: np.ndarray) -> float:
    """Size of the rotation R_a^T R_b in units of the attitude's 1-sigma (covariance [rad^2])."""
    d = matrix_to_rotation_vector(rot_a.T @ rot_b)
    return float(np.sqrt(d @ np.linalg.solve(covariance, d)))


def worst_noisy_quest_vs_svd(seed: int, n: int, ratio: float, trials: int = 400) -> float:
    """
    Return the largest QUEST-SVD difference over noisy trials in the camera field.

    In units of the attitude's own 1-sigma (QUEST covariance).
    """
    rng = np.random.default_rng(seed)
    worst = 0.0
    for k in range(trials):
        truth = random_rotation(rng, ("any", "near_pi")[k % 2])
        body = body_directions(rng, n, "fov")
        sigmas = sigmas_with_ratio(rng, n, ratio, smallest=0.05 * PIXEL)
        measured = noisy(rng, body, sigmas)
        q, s = quest(measured, body @ truth.T, sigmas), svd_attitude(measured, body @ truth.T, sigmas)
        worst = max(worst, mahalanobis(q.rotation, s.rotation, q.covariance))
    return worst


@pytest.mark.parametrize("n", [2, 3])
def test_quest_is_as_accurate_as_svd_with_two_or_three_noisy_stars(n):
    # Spot sigmas from 0.05 px (the identifier's floor) to 0.5 px, as in the pipeline.
    assert worst_noisy_quest_vs_svd(3, n, ratio=10.0) < 1e-3


@pytest.mark.parametrize("ratio", [100.0, 1000.0])
def test_quest_with_two_close_stars_and_very_unequal_weights(ratio):
    assert worst_noisy_quest_vs_svd(4, 2, ratio=ratio, trials=200) < 1e-3


def monte_carlo_nees(seed: int, body: np.ndarray, sigmas: np.ndarray, trials: int = 2000):
    """
    QUEST on `trials` noisy copies of one geometry at a random attitude.

    Per-trial NEES (trials, 3): 3-DOF, cross-boresight 2-DOF (x/y block of the covariance),
    roll 1-DOF.
    """
    rng = np.random.default_rng(seed)
    truth = random_rotation(rng, "any")
    ref = body @ truth.T
    nees = np.empty((trials, 3))
    for k in range(trials):
        solution = quest(noisy(rng, body, sigmas), ref, sigmas)
        d = matrix_to_rotation_vector(truth.T @ solution.rotation)  # R_est = R_true exp([d]x)
        p = solution.covariance
        nees[k] = (d @ np.linalg.solve(p, d), d[:2] @ np.linalg.solve(p[:2, :2], d[:2]), d[2] ** 2 / p[2, 2])
    return nees


@pytest.mark.parametrize("n", [3, 20])
def test_covariance_matches_monte_carlo_scatter(n):
    rng = np.random.default_rng(10 + n)
    body = body_directions(rng, n, "fov")
    sigmas = rng.uniform(0.05, 0.3, n) * PIXEL
    nees = monte_carlo_nees(20 + n, body, sigmas)
    mean = nees.mean(axis=0)
    # Standard errors of the means over 2000 trials: 0.055, 0.045, 0.032.
    assert abs(mean[0] - 3.0) < 0.2
    assert abs(mean[1] - 2.0) < 0.15  # cross-boresight block
    assert abs(mean[2] - 1.0) < 0.1  # roll
    assert abs(np.mean(nees[:, 0] > 13.93) - 0.003) < 0.004  # chi2_3(0.997) tail


def test_two_star_covariance_is_finite_but_large_about_their_bisector():
    separation = np.radians(3.0)
    body = np.array([[-np.sin(separation / 2), 0.0, np.cos(separation / 2)],
                     [np.sin(separation / 2), 0.0, np.cos(separation / 2)]])
    sigma = 0.1 * PIXEL
    covariance = attitude_covariance(body, np.full(2, sigma))
    values, vectors = np.linalg.eigh(covariance)
    assert np.all(np.isfinite(covariance))
    # Rotation about the bisector (here the boresight) moves both stars by only sin(sep/2):
    # variance sigma^2 / (2 sin^2(sep/2)) there, vs sigma^2 / 2 and ~ sigma^2 / 2 about the others.
    assert abs(vectors[2, 2]) > 0.999999
    assert values[2] == pytest.approx(sigma**2 / (2 * np.sin(separation / 2) ** 2), rel=1e-6)
    assert values[2] / values[0] > 1000
    nees = monte_carlo_nees(30, body, np.full(2, sigma))
    assert abs(nees[:, 0].mean() - 3.0) < 0.2  # and the scatter follows it
    assert abs(nees[:, 2].mean() - 1.0) < 0.1  # about the weak axis too


def test_parallel_vectors_give_no_false_confidence_about_their_axis():
    body = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    sigma = 0.1 * PIXEL
    covariance = attitude_covariance(body, np.full(2, sigma))
    assert np.all(np.isfinite(covariance))
    assert covariance[2, 2] > 1e6 * sigma**2
