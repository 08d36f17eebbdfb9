# SPDX-License-Identifier: Apache-2.0
"""
The attitude_fusion node's conversion pieces, on real message classes (no ROS graph needed).

matched_stars' per-star `sigma` (encoded by the identifier, decoded by the fusion), checked
against a finite-difference Jacobian of the camera model rather than the code's own; the
rays the node makes of the matched pixels and camera_info, checked against the stars; the
head attitude, rate and alignment messages; what the fusion status says of each head.
"""
from __future__ import annotations

import numpy as np
import pytest

from star_tracker.centroid import Spots
from star_tracker.identify.base import SOLVED, Identification
from star_tracker.models.attitude import (ARCSEC, matrix_to_quaternion, matrix_to_rotation_vector, quaternion_to_matrix,
                                          radec_roll_to_matrix)
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


# --- the fusion node's side: matched_stars -> one head's observation ---------------------------

def matched_records(camera: CameraModel, rotation: np.ndarray, sigma_rad: float = 1e-5, count: int = 12) -> np.ndarray:
    """Return MATCH_DTYPE records of stars a head at `rotation` (head -> ICRS) sees exactly, and their rays."""
    rng = np.random.default_rng(3)
    u, v = rng.uniform(20, camera.width - 20, count), rng.uniform(20, camera.height - 20, count)
    rays = camera.pixel_to_ray(u, v)
    stars = np.zeros(count, convert.MATCH_DTYPE)
    stars["x"], stars["y"], stars["z"] = (rays @ rotation.T).T
    stars["pixel_x"], stars["pixel_y"], stars["sigma"] = u, v, sigma_rad
    stars["hip_id"] = np.arange(count)
    return stars


@pytest.mark.parametrize("camera", [CAMERA, DISTORTED], ids=["pinhole", "distorted"])
def test_rays_from_pixels_and_camera_info_point_at_the_stars(camera):
    """The head-frame rays the node makes of pixel_x, pixel_y through the decoded camera_info, turned to ICRS."""
    from star_tracker.ros.attitude_fusion_node import head_rays

    rotation = radec_roll_to_matrix(1.2, 0.4, -0.3)
    stars = matched_records(camera, rotation)
    decoded = convert.info_to_camera(convert.camera_to_info(camera, 7, "head1_optical"))
    rays = head_rays(stars, decoded)
    catalog = np.column_stack([stars["x"], stars["y"], stars["z"]]).astype(float)
    angle = np.linalg.norm(rays @ rotation.T - catalog / np.linalg.norm(catalog, axis=1, keepdims=True), axis=1)
    assert np.all(angle < 0.05 * ARCSEC)  # float32 pixels and vectors: ~0.02"
    assert np.allclose(np.linalg.norm(rays, axis=1), 1.0)


def test_head_solution_leaves_out_outliers_and_carries_the_head_attitude():
    from star_tracker.ros.attitude_fusion_node import head_solution

    rotation = radec_roll_to_matrix(0.3, -0.2, 0.1)
    stars = matched_records(CAMERA, rotation, sigma_rad=2e-6)
    stars["residual"] = 1e-6
    stars["residual"][[2, 5]] = 11e-6  # beyond 5 sigma: the identifier's fit left them out
    stars["sigma"][7] = np.nan  # kept here: the fusion's screening counts it
    mounting = quaternion_to_matrix(np.array([0.5, 0.5, 0.5, 0.5])).T
    covariance = np.diag([1e-12, 1e-12, 1e-10])
    solution = head_solution("head2", 123, mounting, stars, CAMERA, 5.0, (rotation, covariance))
    observation = solution.observation
    assert solution.outliers == 2 and observation.rays.shape == (10, 3)
    assert observation.head == "head2" and observation.stamp_ns == 123 and observation.mounting is mounting
    assert np.isnan(observation.ray_sigmas[5]) and observation.ray_sigmas[0] == pytest.approx(2e-6)
    assert np.allclose(observation.rays @ rotation.T, observation.catalog_vectors, atol=1e-6)
    assert observation.head_rotation is rotation and observation.head_covariance is covariance


def test_in_orbit_the_fusion_fits_the_apparent_places_erfa_makes():
    """
    In orbit the fusion fits the stars' apparent places, as ERFA's eraAb makes them.

    matched_stars carry the astrometric catalog. Given the observer's velocity the fused attitude
    is the true one; without it, it is off by about v/c (~25").
    """
    import erfa

    from star_tracker.fuse import BodyRate, FusionConfig, FusionState
    from star_tracker.ros.attitude_fusion_node import head_solution

    rotation = radec_roll_to_matrix(2.1, 0.5, 0.7)  # head -> ICRS, also the body (identity mounting)
    boresight = rotation[:, 2]
    velocity = 29_800.0 * np.cross(boresight, [0.0, 0.0, 1.0]) / np.linalg.norm(np.cross(boresight, [0, 0, 1.0]))
    velocity += 7_600.0 * rotation[:, 0]  # the Earth's orbit and the spacecraft's, across the line of sight
    rng = np.random.default_rng(5)
    u, v = rng.uniform(30, CAMERA.width - 30, 15), rng.uniform(30, CAMERA.height - 30, 15)
    catalog = CAMERA.pixel_to_ray(u, v) @ rotation.T  # astrometric directions near the field
    beta = velocity / 299_792_458.0
    apparent = erfa.ab(catalog, beta, 1.0, np.sqrt(1.0 - beta @ beta))
    pixel_u, pixel_v, seen = CAMERA.project(apparent @ rotation)
    assert np.all(seen)
    stars = np.zeros(15, convert.MATCH_DTYPE)
    stars["x"], stars["y"], stars["z"] = catalog.T
    stars["pixel_x"], stars["pixel_y"], stars["sigma"] = pixel_u, pixel_v, 1e-6

    def fused_error_arcsec(velocity_m_s) -> float:
        state = FusionState(FusionConfig(("head1",), stale_after_s=1.0))
        observation = head_solution("head1", 10, np.eye(3), stars, CAMERA, 5.0, None, velocity_m_s).observation
        assert state.add(observation).accepted
        fused = state.fused_at(10, BodyRate(np.zeros(3), np.eye(3) * 1e-12))
        return float(np.linalg.norm(matrix_to_rotation_vector(rotation.T @ fused.rotation))) / ARCSEC

    assert fused_error_arcsec(velocity) < 0.1  # float32 pixels and vectors: ~0.02"
    assert 15.0 < fused_error_arcsec(None) < 30.0


def test_the_head_attitude_message_is_checked_and_read_as_head_to_icrs():
    from geometry_msgs.msg import PoseWithCovarianceStamped

    from star_tracker.models.attitude_estimation import AttitudeSolution
    from star_tracker.ros.attitude_fusion_node import pose_attitude

    rotation = radec_roll_to_matrix(2.0, 0.5, 1.0)
    covariance = np.array([[1e-12, 2e-13, 0.0], [2e-13, 2e-12, 0.0], [0.0, 0.0, 5e-11]])
    msg = convert.pose_with_covariance_msg(AttitudeSolution(matrix_to_quaternion(rotation), rotation, covariance, 0.0),
                                           9, "icrs")
    back, back_covariance = pose_attitude(msg)
    assert np.allclose(back, rotation, atol=1e-12) and np.allclose(back_covariance, covariance)
    bad = PoseWithCovarianceStamped()
    bad.pose.pose.orientation.w = 0.9
    with pytest.raises(ValueError, match="not a unit quaternion"):
        pose_attitude(bad)
    msg.pose.covariance[35] = -1.0
    with pytest.raises(ValueError, match="rotation covariance"):
        pose_attitude(msg)


def test_a_heads_rate_is_turned_to_the_body_frame():
    from star_tracker.ros.attitude_fusion_node import twist_body_rate
    from star_tracker.track.rate import RateEstimate

    mounting = quaternion_to_matrix(np.array([0.5, 0.5, 0.5, 0.5])).T  # head2: boresight along body +X
    rate_head = np.array([1e-3, 2e-3, 3e-3])  # head2's roll rate is about its z = body x
    covariance = np.diag([1e-8, 1e-8, 1e-6])
    msg = convert.rate_with_covariance_msg(RateEstimate(5, rate_head, covariance, 4), "head2_optical")
    body = twist_body_rate(msg, mounting)
    assert np.allclose(body.rate, [3e-3, 1e-3, 2e-3])
    assert np.allclose(np.diag(body.covariance), [1e-6, 1e-8, 1e-8])
    assert np.allclose(twist_body_rate(msg).rate, rate_head)  # a body_rate message is in the body frame
    msg.twist.twist.angular.x = float("nan")
    with pytest.raises(ValueError, match="3 finite values"):
        twist_body_rate(msg, mounting)


def test_the_alignment_message_is_the_correction_as_a_body_frame_rotation():
    from star_tracker.ros.attitude_fusion_node import correction_msg

    correction = np.array([2.0, -1.0, 0.5]) * ARCSEC
    covariance = np.diag([4.0, 1.0, 9.0]) * ARCSEC ** 2
    msg = correction_msg(correction, covariance, 42, "body")
    o = msg.pose.pose.orientation
    assert msg.header.frame_id == "body" and convert.stamp_to_ns(msg.header.stamp) == 42
    assert np.allclose(matrix_to_rotation_vector(quaternion_to_matrix(np.array([o.x, o.y, o.z, o.w]))), correction)
    block = np.asarray(msg.pose.covariance).reshape(6, 6)
    assert np.allclose(block[3:, 3:], covariance) and np.all(np.diag(block)[:3] == -1.0)


@pytest.mark.parametrize("used, refusal_kind, dropped, state", [
    (True, "", "", "contributing"),
    (False, "", "no observation yet", "no solution"),
    (False, "", "stale: latest observation +0.500 s from the stamp (window 0.3 s)", "stale"),
    (False, "missing_camera_info", "no observation yet", "missing camera_info"),
    (False, "too_few_stars", "stale: latest observation +0.500 s from the stamp (window 0.3 s)", "excluded"),
    (False, "out_of_order", "", "excluded"),
])
def test_each_heads_state_in_the_fusion_status(used, refusal_kind, dropped, state):
    from star_tracker.ros.attitude_fusion_node import HeadInput, head_state

    head = HeadInput("head1", np.eye(3), refusal_kind=refusal_kind, refusal="why" if refusal_kind else "")
    found = head_state(head, used, dropped)
    assert found.state == state
    assert (found.reason == "") == used
    assert not found.reason.startswith("stale")  # the state says it already
