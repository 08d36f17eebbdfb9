# SPDX-License-Identifier: Apache-2.0
"""
Camera self-calibration (models/camera_calibration.py) against the simulator's truth.

Frames rendered through a distorted camera with an off-centre principal point, centroided, each
spot matched to the star that made it; the fit must recover the true camera within its own
stated uncertainty (3 sigma). Real images: test/commands/test_calibrate.py.
"""
import math

import numpy as np
import pytest

from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.models.attitude import radec_roll_to_matrix, rotation_vector_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.models.camera_calibration import (CalibrationConfig, CalibrationFrame, calibrate_camera,
                                                    constrained)
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel

WIDTH, HEIGHT = 1024, 768
FOV_RAD = math.radians(25.0)
TRUE_DISTORTION = (0.18, 0.0, 0.0, 0.0, 0.0)
TRUE_OFFSET_PX = (9.0, -7.0)  # principal point minus image centre
POINTINGS = [(1.4, 0.35, 0.2), (3.1, -0.4, 1.0), (5.0, 0.9, -0.6)]  # RA, Dec, roll [rad]


def true_camera() -> CameraModel:
    nominal = CameraModel.from_fov(WIDTH, HEIGHT, FOV_RAD)
    return CameraModel(WIDTH, HEIGHT, nominal.fx, nominal.fy, nominal.cx + TRUE_OFFSET_PX[0],
                       nominal.cy + TRUE_OFFSET_PX[1], TRUE_DISTORTION)


def starting_camera() -> CameraModel:
    """Return what a --fov user knows: a pinhole 0.4 % off in focal length, centred, undistorted."""
    return CameraModel.from_fov(WIDTH, HEIGHT, FOV_RAD * 1.004)


@pytest.fixture(scope="module")
def frames(catalog):
    """
    Return one CalibrationFrame per pointing (rendering: the tests using it are slow).

    Measured spots matched (within 2 px) to the true stars, starting attitude the truth turned by ~0.1 deg.
    """
    camera = true_camera()
    renderer = StarFieldRenderer(camera, SensorModel(), catalog, magnitude_limit=6.5)
    by_hip = dict(zip(renderer.catalog.hip.tolist(), renderer.star_vectors))
    out = []
    for k, pointing in enumerate(POINTINGS):
        frame = renderer.render(ConstantRateMotion(radec_roll_to_matrix(*pointing), np.zeros(3)), 10.0,
                                frame_seed(0, k))
        spots = extract_spots(frame.image, CentroidConfig(max_spots=120))
        truth = frame.truth
        stars = np.flatnonzero(truth.stars())
        distance = np.hypot(spots.x[:, None] - truth.x[stars][None], spots.y[:, None] - truth.y[stars][None])
        nearest = distance.argmin(axis=1)
        matched = distance[np.arange(len(spots)), nearest] < 2.0
        hip = truth.hip[stars][nearest[matched]]
        out.append(CalibrationFrame(spots.x[matched], spots.y[matched], spots.cov[matched],
                                    np.array([by_hip[h] for h in hip]),
                                    truth.rotation @ rotation_vector_to_matrix([1e-3, -2e-3, 1e-3])))
    return out


def assert_within_3_sigma(calibration, names):
    truth = true_camera()
    values = {"f": truth.fx, "cx": truth.cx, "cy": truth.cy, "k1": truth.distortion[0], "k2": truth.distortion[1]}
    for name in names:
        assert name in calibration.fitted
        error = calibration.value[name] - values[name]
        assert abs(error) <= 3.0 * calibration.sigma[name], (name, calibration.value[name], values[name],
                                                             calibration.sigma[name])


def test_projected_stars_with_noise_recover_the_camera(catalog):
    """Fast lane: catalog stars projected through the true camera plus 0.2 px Gaussian noise."""
    rng = np.random.default_rng(4)
    camera, vectors = true_camera(), catalog.brighter_than(6.0).unit_vectors()
    frames = []
    for pointing in POINTINGS:
        rotation = radec_roll_to_matrix(*pointing)
        u, v, front = camera.project(vectors @ rotation)
        seen = front & camera.in_image(u, v, margin=5.0)
        n = int(seen.sum())
        frames.append(CalibrationFrame(u[seen] + rng.normal(0, 0.2, n), v[seen] + rng.normal(0, 0.2, n),
                                       np.tile(0.04 * np.eye(2), (n, 1, 1)), vectors[seen],
                                       rotation @ rotation_vector_to_matrix([2e-3, 1e-3, -1e-3])))
    calibration = calibrate_camera(frames, starting_camera(), CalibrationConfig(sigma_floor_px=0.0))
    assert set(calibration.fitted) == {"f", "k1", "k2", "cx", "cy"}
    assert_within_3_sigma(calibration, ["f", "k1", "k2", "cx", "cy"])
    assert 0.15 < calibration.residual_rms_px < 0.25  # the noise put in


@pytest.mark.slow
def test_joint_fit_recovers_focal_length_distortion_and_principal_point(frames):
    calibration = calibrate_camera(frames, starting_camera())
    assert set(calibration.fitted) == {"f", "k1", "k2", "cx", "cy"}, calibration.as_dict()
    assert_within_3_sigma(calibration, ["f", "k1", "k2", "cx", "cy"])
    assert calibration.sigma["k1"] < 0.02 and calibration.sigma["cx"] < 3.0  # constrained, not just wide
    assert calibration.residual_rms_px < 0.3
    assert constrained(calibration, CalibrationConfig())
    for rotation, frame in zip(calibration.rotations, frames):  # attitudes back to the truth (start was 0.13 deg off)
        truth = frame.rotation @ rotation_vector_to_matrix([1e-3, -2e-3, 1e-3]).T
        angle = math.acos(np.clip((np.trace(truth.T @ rotation) - 1.0) / 2.0, -1.0, 1.0))
        assert angle < math.radians(0.01)


@pytest.mark.slow
def test_one_frame_fits_focal_length_and_k1(frames):
    calibration = calibrate_camera(frames[:1], starting_camera(), CalibrationConfig(fit=("f", "k1")))
    assert calibration.fitted == ("f", "k1")
    assert_within_3_sigma(calibration, ["f", "k1"])


@pytest.mark.slow
def test_a_wrong_match_is_left_out(frames):
    frame = frames[0]
    stars = frame.stars.copy()
    stars[[2, 5]] = stars[[5, 2]]  # two stars swapped: two wrong matches, tens of pixels off
    wrong = CalibrationFrame(frame.x, frame.y, frame.cov, stars, frame.rotation)
    calibration = calibrate_camera([wrong, *frames[1:]], starting_camera())
    assert not calibration.inliers[0][2] and not calibration.inliers[0][5]
    assert calibration.inliers[0].sum() >= frame.size - 3
    assert_within_3_sigma(calibration, ["f", "k1"])


@pytest.mark.slow
def test_stars_near_the_centre_fit_the_focal_length_only(frames):
    frame = frames[0]
    near = np.hypot(frame.x - WIDTH / 2, frame.y - HEIGHT / 2) < 150.0
    assert 3 <= near.sum() < 30
    central = CalibrationFrame(frame.x[near], frame.y[near], frame.cov[near], frame.stars[near], frame.rotation)
    calibration = calibrate_camera([central], starting_camera())
    assert "k2" in calibration.not_fitted and "principal_point" in calibration.not_fitted
    assert calibration.camera.cx == starting_camera().cx and calibration.camera.distortion[1] == 0.0


@pytest.mark.slow
def test_bad_input_is_refused(frames):
    frame = frames[0]
    with pytest.raises(ValueError, match="cov must be finite"):
        CalibrationFrame(frame.x, frame.y, frame.cov[:-1], frame.stars, frame.rotation)
    with pytest.raises(ValueError, match=">= 3 matched stars"):
        calibrate_camera([CalibrationFrame(frame.x[:2], frame.y[:2], frame.cov[:2], frame.stars[:2], frame.rotation)],
                         starting_camera())
    with pytest.raises(ValueError, match="at least one frame"):
        calibrate_camera([], starting_camera())
    with pytest.raises(ValueError, match="unknown calibration parameter"):
        CalibrationConfig(fit=("f", "k7"))


@pytest.mark.parametrize("frame_count", [1, 3])
def test_analytic_jacobian_matches_finite_differences(frame_count):
    """The fit's analytic derivatives (rotations, f, k1, k2, cx, cy; p1, p2, k3 set) against central differences."""
    from star_tracker.models import camera_calibration as calibration

    rng = np.random.default_rng(7)
    camera = CameraModel(WIDTH, HEIGHT, 900.0, 905.0, 510.0, 380.0, (-0.1, 0.03, 1e-3, -2e-3, 0.01))
    frames = []
    for _ in range(frame_count):
        rotation = rotation_vector_to_matrix(rng.normal(size=3))
        rays = np.column_stack([rng.uniform(-0.5, 0.5, 12), rng.uniform(-0.4, 0.4, 12), np.ones(12)])
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        u, v, _ = camera.project(rays)
        frames.append(CalibrationFrame(u + rng.normal(size=12), v + rng.normal(size=12),
                                       np.tile(np.diag([0.3, 0.5]), (12, 1, 1)), rays @ rotation.T, rotation))
    names = ("f", "k1", "k2", "cx", "cy")
    bounds = np.concatenate([[0], np.cumsum([f.size for f in frames])])
    measured = np.concatenate([np.stack([f.x, f.y], axis=-1) for f in frames])
    model = calibration._whitened_model(frames, camera, names, calibration._whitening(frames, 0.3), measured, bounds)
    params = np.concatenate([rng.normal(scale=0.05, size=3 * frame_count), [0.01, -0.08, 0.02, 1.5, -2.0]])
    _, jacobian = model(params)
    jacobian = jacobian.toarray() if hasattr(jacobian, "toarray") else jacobian
    numeric = np.empty_like(jacobian)
    for i in range(params.size):
        step = np.zeros_like(params)
        step[i] = 1e-6
        numeric[:, i] = (model(params + step)[0] - model(params - step)[0]) / 2e-6
    assert np.max(np.abs(jacobian - numeric)) < 1e-6 * np.max(np.abs(numeric))


def test_hundreds_of_frames_recover_the_camera_with_the_full_inverse_s_covariance(catalog):
    """
    400 frames (a long bag): the camera within 3 sigma of the truth, sigma shrinking as 1/sqrt(frames).

    The camera block of the covariance, computed without the full inverse (rotations eliminated
    per frame), equals the full inverse's on a smaller set.
    """
    from star_tracker.models import camera_calibration as calibration

    rng = np.random.default_rng(11)
    camera, vectors = true_camera(), catalog.brighter_than(6.0).unit_vectors()

    def frames_of(count):
        frames = []
        for _ in range(count):
            rotation = rotation_vector_to_matrix(rng.normal(size=3))
            u, v, front = camera.project(vectors @ rotation)
            seen = np.flatnonzero(front & camera.in_image(u, v, margin=5.0))[:40]
            n = seen.size
            frames.append(CalibrationFrame(u[seen] + rng.normal(0, 0.2, n), v[seen] + rng.normal(0, 0.2, n),
                                           np.tile(0.04 * np.eye(2), (n, 1, 1)), vectors[seen],
                                           rotation @ rotation_vector_to_matrix(rng.normal(0, 1e-3, 3))))
        return [f for f in frames if f.size >= 3]

    config = CalibrationConfig(sigma_floor_px=0.0)
    few, many = frames_of(20), frames_of(400)
    assert len(many) > 350
    small, large = calibrate_camera(few, starting_camera(), config), calibrate_camera(many, starting_camera(), config)
    for result in (small, large):
        assert set(result.fitted) == {"f", "k1", "k2", "cx", "cy"}
        assert_within_3_sigma(result, ["f", "k1", "k2", "cx", "cy"])
    ratio = math.sqrt(large.stars / small.stars)
    for name in ("f", "k1", "cx"):
        assert 0.6 * ratio < small.sigma[name] / large.sigma[name] < 1.6 * ratio, (name, small.sigma, large.sigma)

    names = ("f", "k1", "k2", "cx", "cy")
    bounds = np.concatenate([[0], np.cumsum([f.size for f in few])])
    measured = np.concatenate([np.stack([f.x, f.y], axis=-1) for f in few])
    model = calibration._whitened_model(few, camera, names, calibration._whitening(few, 0.0), measured, bounds)
    params = np.concatenate([rng.normal(scale=1e-3, size=3 * len(few)), [0.0, 0.18, 0.0, 0.0, 0.0]])
    jacobian = model(params)[1]
    full = np.linalg.inv((jacobian.T @ jacobian).toarray())[3 * len(few):, 3 * len(few):]
    np.testing.assert_allclose(calibration._camera_covariance(jacobian, len(few)), full, rtol=1e-6)
