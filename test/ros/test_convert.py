# SPDX-License-Identifier: Apache-2.0
"""Message <-> record conversion (real ROS message classes, no ROS graph needed)."""
import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from star_tracker.models.attitude import matrix_to_quaternion, radec_roll_to_matrix
from star_tracker.models.attitude_estimation import AttitudeSolution
from star_tracker.models.camera import CameraModel
from star_tracker.centroid import Spots
from star_tracker.ros import convert


def test_mono16_and_mono8_round_trip():
    rng = np.random.default_rng(0)
    for dtype in (np.uint16, np.uint8):
        array = rng.integers(0, np.iinfo(dtype).max, (7, 5), dtype=dtype)
        msg = convert.array_to_image(array, 1_700_000_000_123_456_789, "star_tracker_optical")
        assert msg.encoding == ("mono16" if dtype == np.uint16 else "mono8")
        assert convert.stamp_to_ns(msg.header.stamp) == 1_700_000_000_123_456_789
        assert np.array_equal(convert.image_to_array(msg), array)


def test_big_endian_and_padded_rows_are_decoded():
    array = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    msg = Image(height=3, width=4, encoding="mono16", is_bigendian=1, step=10)
    padded = np.zeros((3, 10), np.uint8)
    padded[:, :8] = array.astype(">u2").view(np.uint8).reshape(3, 8)
    msg.data = padded.tobytes()
    assert np.array_equal(convert.image_to_array(msg), array)


@pytest.mark.parametrize("change, match", [
    (dict(encoding="rgb8"), "unsupported image encoding"),
    (dict(step=3), "step"),
    (dict(height=0), "empty image"),
    (dict(data=b"\x00" * 7), "data size"),
])
def test_malformed_images_raise_clear_errors(change, match):
    msg = Image(height=2, width=2, encoding="mono16", is_bigendian=0, step=4, data=b"\x00" * 8)
    for key, value in change.items():
        setattr(msg, key, value)
    with pytest.raises(ValueError, match=match):
        convert.image_to_array(msg)


def test_camera_info_round_trip_and_validation():
    camera = CameraModel(1024, 768, 3900.0, 3890.0, 515.3, 380.9, (-0.12, 0.05, 1e-4, -2e-4, 0.01))
    back = convert.info_to_camera(convert.camera_to_info(camera, 5, "star_tracker_optical"))
    assert back == camera
    bad = convert.camera_to_info(camera, 5, "x")
    bad.k = [float("nan")] * 9
    with pytest.raises(ValueError, match="K must be 9 finite"):
        convert.info_to_camera(bad)
    bad = convert.camera_to_info(camera, 5, "x")
    bad.k = [0.0] * 9
    with pytest.raises(ValueError, match="invalid camera model"):
        convert.info_to_camera(bad)
    with pytest.raises(ValueError, match="invalid camera model"):
        convert.info_to_camera(CameraInfo())


def test_spots_cloud_round_trip_and_layout():
    n = 4
    cov = np.tile(np.array([[0.04, 0.01], [0.01, 0.09]]), (n, 1, 1))
    spots = Spots(np.arange(n) + 0.25, np.arange(n) + 0.5, np.full(n, 1e4), np.full(n, 80.0), cov,
                  np.array([0, 1, 2, 4], np.uint32), np.ones(n, np.int32), np.ones(n), 1024, 1024,
                  streak_length=np.array([0.0, 0.0, 0.0, 21.5]), streak_angle=np.array([0.0, 0.0, 0.0, -1.25]))
    msg = convert.spots_to_cloud(spots, 42, "star_tracker_optical")
    assert msg.point_step == 40 and msg.row_step == 40 * n and msg.height == 1 and msg.width == n
    assert [(f.name, f.offset) for f in msg.fields] == [("x", 0), ("y", 4), ("flux", 8), ("snr", 12), ("cov_xx", 16),
                                                        ("cov_xy", 20), ("cov_yy", 24), ("flags", 28),
                                                        ("streak_length", 32), ("streak_angle", 36)]
    back = convert.cloud_to_spots(msg, 1024, 1024)
    assert np.allclose(back.x, spots.x) and np.allclose(back.y, spots.y)
    assert np.allclose(back.cov, spots.cov) and np.array_equal(back.flags, spots.flags)
    assert np.allclose(back.streak_length, spots.streak_length) and np.allclose(back.streak_angle, spots.streak_angle)


def test_malformed_spot_clouds_raise_clear_errors():
    msg = PointCloud2(height=1, width=3, point_step=12, data=b"\x00" * 36)
    with pytest.raises(ValueError, match="unexpected PointCloud2 layout"):
        convert.cloud_to_spots(msg, 10, 10)
    good = convert.spots_to_cloud(Spots.empty(10, 10), 1, "f")
    good.width = 2  # claims two points, carries none
    with pytest.raises(ValueError, match="bytes, expected"):
        convert.cloud_to_spots(good, 10, 10)


def test_pose_with_covariance_layout():
    rot = radec_roll_to_matrix(1.0, 0.2, 0.3)
    cov = np.diag([1e-10, 2e-10, 3e-9])
    msg = convert.pose_with_covariance_msg(AttitudeSolution(matrix_to_quaternion(rot), rot, cov, 0.0), 7)
    full = np.asarray(msg.pose.covariance).reshape(6, 6)
    assert np.allclose(full[3:, 3:], cov)
    assert np.all(np.diag(full)[:3] == -1.0)  # position unknown
    assert msg.header.frame_id == "icrs" and convert.stamp_to_ns(msg.header.stamp) == 7


def test_big_endian_arrays_are_encoded_as_mono16():
    array = (np.arange(6, dtype=np.uint16).reshape(2, 3) * 4097).astype(">u2")
    msg = convert.array_to_image(array, 1, "f")
    assert msg.encoding == "mono16" and msg.is_bigendian == 0
    assert np.array_equal(convert.image_to_array(msg), array)
    with pytest.raises(ValueError, match="uint8/uint16"):
        convert.array_to_image(np.zeros((2, 2), np.float32), 1, "f")


def test_stamps_outside_builtin_time_are_refused():
    assert convert.stamp_to_ns(convert.ns_to_stamp(-1)) == -1  # before 1970: representable
    with pytest.raises(ValueError, match="int32 seconds"):
        convert.ns_to_stamp(2**31 * 10**9)


def test_camera_info_with_a_wild_distortion_or_size_is_refused():
    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0), (-0.05, 0.01, 0.0, 0.0, 0.0))
    assert convert.info_to_camera(convert.camera_to_info(camera, 1, "f")) == camera
    bad = convert.camera_to_info(camera, 1, "f")
    bad.d = [-50.0, 0.0, 0.0, 0.0, 0.0]  # folds back on itself inside the image
    with pytest.raises(ValueError, match="no usable field of view"):
        convert.info_to_camera(bad)
    bad = convert.camera_to_info(camera, 1, "f")
    bad.width = bad.height = 2**20
    with pytest.raises(ValueError, match="pixel limit"):
        convert.info_to_camera(bad)


def test_spot_clouds_with_multi_count_fields_or_too_many_points_are_refused():
    msg = convert.spots_to_cloud(Spots.empty(10, 10), 1, "f")
    msg.fields[0].count = 3
    with pytest.raises(ValueError, match="unexpected PointCloud2 layout"):
        convert.cloud_to_spots(msg, 10, 10)
    msg = convert.spots_to_cloud(Spots.empty(10, 10), 1, "f")
    msg.width, msg.height = 2**16, 2**16
    with pytest.raises(ValueError, match="point limit"):
        convert.cloud_to_spots(msg, 10, 10)


def test_invalid_spots_are_dropped_and_counted():
    nan, inf = np.nan, np.inf
    x = np.array([10.0, nan, 20.0, 30.0, 40.0, -12.0, 50.0, 60.0])
    y = np.array([10.0, 10.0, inf, 30.0, 40.0, 10.0, 50.0, 1033.4])
    flux = np.array([1.0, 1.0, 1.0, nan, 1.0, 1.0, 1.0, 1.0])
    cov = np.tile(np.eye(2) * 0.04, (8, 1, 1))
    cov[4] = np.eye(2) * 1e6  # 1000 px 1-sigma: no measurement
    cov[6, 0, 0] = -1.0
    spots = Spots(x, y, flux, np.ones(8), cov, np.zeros(8, np.uint32), np.ones(8, np.int32), np.ones(8), 1024, 1024)
    kept, dropped = convert.drop_invalid_spots(spots)
    assert dropped == 6
    assert list(kept.x) == [10.0, 60.0]  # in the image, and 1033.4 is within the 10 px margin of 1023.5
    assert convert.drop_invalid_spots(kept) == (kept, 0)
    twice = Spots(np.array([5.0, 7.0, 5.0]), np.array([6.0, 8.0, 6.0]), np.array([3.0, 2.0, 1.0]), np.ones(3),
                  np.zeros((3, 2, 2)), np.zeros(3, np.uint32), np.ones(3, np.int32), np.ones(3), 1024, 1024)
    kept, dropped = convert.drop_invalid_spots(twice)  # coincident spots: the first (brightest) kept
    assert dropped == 1 and list(kept.flux) == [3.0, 2.0]
