# SPDX-License-Identifier: Apache-2.0
import cv2
import numpy as np
import pytest

from star_tracker.models.camera import CameraModel

DISTORTED = CameraModel(1024, 768, 3900.0, 3890.0, 515.3, 380.9, (-0.12, 0.05, 1e-4, -2e-4, 0.01))


@pytest.mark.parametrize("camera", [CameraModel.from_fov(1024, 1024, np.radians(15.0)), DISTORTED])
def test_projection_round_trip(camera):
    rng = np.random.default_rng(1)
    u = rng.uniform(0, camera.width - 1, 500)
    v = rng.uniform(0, camera.height - 1, 500)
    rays = camera.pixel_to_ray(u, v)
    assert np.allclose(np.linalg.norm(rays, axis=1), 1.0)
    u2, v2, front = camera.project(rays)
    assert front.all()
    assert np.max(np.hypot(u2 - u, v2 - v)) < 1e-3


def test_projection_matches_opencv():
    rng = np.random.default_rng(2)
    rays = np.column_stack([rng.uniform(-0.12, 0.12, 200), rng.uniform(-0.09, 0.09, 200), np.ones(200)])
    u, v, _ = DISTORTED.project(rays)
    ref, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), DISTORTED.intrinsic_matrix(),
                               np.asarray(DISTORTED.distortion))
    assert np.max(np.hypot(ref[:, 0, 0] - u, ref[:, 0, 1] - v)) < 1e-9


def test_directions_beyond_the_distortion_fold_are_not_imaged():
    """
    Barrel k1 -0.1 (20 deg field): r (1 + k1 r^2) peaks at r^2 = 1/(3 |k1|), 61 deg off-axis.

    Farther directions fold back onto the chip under the polynomial; no lens images them there.
    Every bright star of the sky projected through such a camera put stars from 61-90 deg
    off-axis among the brightest "in the image".
    """
    camera = CameraModel.from_fov(1024, 1024, np.radians(20.0), (-0.1, 0.0, 0.0, 0.0, 0.0))
    assert camera.max_imaged_radius2 == pytest.approx(1.0 / 0.3)
    off_axis = np.radians(np.array([5.0, 30.0, 60.0, 62.0, 75.0, 89.0]))
    rays = np.column_stack([np.sin(off_axis), np.zeros(6), np.cos(off_axis)])
    u, v, imaged = camera.project(rays)
    assert imaged.tolist() == [True, True, True, False, False, False]
    # 72.4 deg off-axis the polynomial puts a star ~60 px from the image centre: what the mask keeps out.
    fold = np.radians(72.4)
    u, v, imaged = camera.project(np.array([[np.sin(fold), 0.0, np.cos(fold)]]))
    assert camera.in_image(u, v).all() and not imaged.any()
    # A subnormal k3 (as a fuzzed CameraInfo gave): no division by it, and no fold.
    for monotonic in [(0.0,) * 5, (0.1, 0.0, 0.0, 0.0, 0.0), DISTORTED.distortion, (0.0, 0.0, 0.0, 0.0, 2.2e-311)]:
        assert CameraModel.from_fov(1024, 1024, np.radians(20.0), monotonic).max_imaged_radius2 == np.inf
    # With k3 the cubic's smallest positive root: the derivative vanishes there.
    s = CameraModel.from_fov(1024, 1024, np.radians(20.0), (-0.3, 0.05, 0.0, 0.0, -0.01)).max_imaged_radius2
    assert 1.0 - 0.9 * s + 0.25 * s ** 2 - 0.07 * s ** 3 == pytest.approx(0.0, abs=1e-12)


def test_optical_frame_axes(nominal_camera):
    # +X right (columns grow), +Y down (rows grow), +Z boresight at the principal point.
    u, v, _ = nominal_camera.project(np.array([[0.0, 0.0, 1.0], [0.01, 0.0, 1.0], [0.0, 0.01, 1.0]]))
    assert u[0] == pytest.approx(nominal_camera.cx) and v[0] == pytest.approx(nominal_camera.cy)
    assert u[1] > u[0] and v[1] == pytest.approx(v[0])
    assert v[2] > v[0] and u[2] == pytest.approx(u[0])


def test_fov_and_pixel_scale(nominal_camera):
    # Gnomonic projection: the scale at the principal point is tan(FOV/2) / (W/2).
    assert nominal_camera.pixel_scale_rad == pytest.approx(np.tan(np.radians(7.5)) / 512, rel=1e-9)
    assert np.degrees(2 * nominal_camera.half_diagonal_fov_rad) == pytest.approx(21.1, abs=0.1)


@pytest.mark.parametrize("kwargs", [dict(fx=0.0), dict(fx=float("nan")), dict(width=0), dict(distortion=(0.0, 0.0))])
def test_invalid_camera_is_rejected(kwargs):
    base = dict(width=640, height=480, fx=500.0, fy=500.0, cx=320.0, cy=240.0, distortion=(0.0,) * 5)
    with pytest.raises(ValueError, match="invalid camera model"):
        CameraModel(**{**base, **kwargs})
