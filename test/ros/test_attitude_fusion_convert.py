# SPDX-License-Identifier: Apache-2.0
"""
The attitude_fusion node's conversion pieces, on real message classes (no ROS graph needed).

matched_stars' per-star `sigma` (encoded by the identifier, decoded by the fusion), checked
against a finite-difference Jacobian of the camera model rather than the code's own.
"""
from __future__ import annotations

import numpy as np
import pytest

from star_tracker.centroid import Spots
from star_tracker.identify.base import SOLVED, Identification
from star_tracker.models.attitude import ARCSEC
from star_tracker.models.camera import CameraModel
from star_tracker.ros import convert

CAMERA = CameraModel.from_fov(1024, 1024, np.radians(15.0))
DISTORTED = CameraModel(1024, 1024, 3900.0, 3890.0, 515.3, 509.9, (-0.12, 0.05, 1e-4, -2e-4, 0.01))


def spots_with(x, y, cov) -> Spots:
    n = len(x)
    return Spots(np.asarray(x, float), np.asarray(y, float), np.full(n, 1e4), np.full(n, 50.0), np.asarray(cov, float),
                 np.zeros(n, np.uint32), np.ones(n, np.int32), np.ones(n), 1024, 1024)


def solved(spot_index, stars: int) -> Identification:
    """Return a solved identification of `stars` stars, with only what matched_stars carries filled."""
    rng = np.random.default_rng(1)
    vectors = rng.normal(size=(stars, 3))
    return Identification(SOLVED, "", "test", 0.0, spot_index=np.asarray(spot_index),
                          hip=np.arange(1, stars + 1, dtype=np.int32),
                          star_vectors=vectors / np.linalg.norm(vectors, axis=1, keepdims=True),
                          residual_rad=np.full(stars, 1e-6), magnitude=np.linspace(2.0, 7.0, stars))


def numeric_sigma(camera: CameraModel, x: float, y: float, cov: np.ndarray) -> float:
    """sqrt(largest eigenvalue of J C J^T), J by central differences of pixel_to_ray (step 0.01 px)."""
    h = 0.01
    jx = (camera.pixel_to_ray(x + h, y) - camera.pixel_to_ray(x - h, y))[0] / (2 * h)
    jy = (camera.pixel_to_ray(x, y + h) - camera.pixel_to_ray(x, y - h))[0] / (2 * h)
    jacobian = np.column_stack([jx, jy])
    return float(np.sqrt(np.linalg.eigvalsh(jacobian @ cov @ jacobian.T)[-1]))


def streak_covariance(along_px: float, across_px: float, angle_rad: float) -> np.ndarray:
    turn = np.array([[np.cos(angle_rad), -np.sin(angle_rad)], [np.sin(angle_rad), np.cos(angle_rad)]])
    return turn @ np.diag([along_px ** 2, across_px ** 2]) @ turn.T


@pytest.mark.parametrize("camera", [CAMERA, DISTORTED], ids=["pinhole", "distorted"])
def test_matched_stars_sigma_round_trip(camera):
    """Round spots and a streak, at the centre and toward a corner: the field's worst-direction 1-sigma."""
    x = [511.5, 40.0, 900.0, 300.0]
    y = [511.5, 60.0, 980.0, 700.0]
    cov = [np.eye(2) * 0.03 ** 2, np.eye(2) * 0.2 ** 2, np.eye(2) * 0.5 ** 2, streak_covariance(2.0, 0.1, 0.7)]
    spots = spots_with(x, y, cov)
    result = solved([3, 1, 0], 3)  # matched spots in another order than the spots'
    msg = convert.identification_to_cloud(result, spots, result.magnitude, 1_700_000_000_000_000_001, "icrs", camera)
    assert msg.point_step == 36 and [f.name for f in msg.fields][-1] == "sigma" and msg.fields[-1].offset == 32
    stars = convert.cloud_to_records(msg, convert.MATCH_FIELDS, convert.MATCH_DTYPE)
    assert list(stars["hip_id"]) == [1, 2, 3]
    for star, spot in zip(stars, result.spot_index):
        expected = numeric_sigma(camera, x[spot], y[spot], cov[spot] + np.eye(2) * 1e-8)  # the fit's 1e-4 px floor
        assert star["sigma"] == pytest.approx(expected, rel=2e-4), spot
        assert (star["pixel_x"], star["pixel_y"]) == pytest.approx((x[spot], y[spot]))
    # The streak's sigma is its error along the smear (2 px), not the mean of its two axes.
    pixel_scale = camera.pixel_scale_rad
    assert stars["sigma"][0] == pytest.approx(2.0 * pixel_scale, rel=0.1)
    assert stars["sigma"][2] == pytest.approx(0.03 * pixel_scale, rel=0.1)  # spot 0, at the centre


def test_matched_stars_sigma_of_the_nominal_camera_at_the_centre():
    """At the principal point a round spot of s px has sigma s / f [rad] exactly (53" per px)."""
    spots = spots_with([CAMERA.cx], [CAMERA.cy], [np.eye(2) * 0.1 ** 2])
    msg = convert.identification_to_cloud(solved([0], 1), spots, np.array([3.0]), 5, "icrs", CAMERA)
    sigma = convert.cloud_to_records(msg, convert.MATCH_FIELDS, convert.MATCH_DTYPE)["sigma"][0]
    assert sigma == pytest.approx(np.hypot(0.1, 1e-4) / CAMERA.fx, rel=1e-6)
    assert sigma / ARCSEC == pytest.approx(5.3, abs=0.1)


def test_an_old_32_byte_matched_stars_message_is_refused_with_its_layout():
    records = np.zeros(2, convert.MATCH_DTYPE)
    old = convert.records_to_cloud(records, convert.MATCH_FIELDS[:-1], 0, "icrs")
    old.point_step, old.row_step, old.data = 32, 64, bytes(64)
    with pytest.raises(ValueError, match="unexpected PointCloud2 layout"):
        convert.cloud_to_records(old, convert.MATCH_FIELDS, convert.MATCH_DTYPE)
