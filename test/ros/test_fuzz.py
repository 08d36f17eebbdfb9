# SPDX-License-Identifier: Apache-2.0
"""
Property-based tests (hypothesis) of the message converters (star_tracker.ros.convert).

On real rclpy message classes filled with garbage: a valid result, or ValueError with a message;
never another exception. Shared strategies and checks: test/fuzz_support.py; the core
functions behind the converters are fuzzed in test/models, test/centroid, test/identify and
test/track (*_fuzz.py).
"""
from __future__ import annotations

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
pytest.importorskip("rclpy")

from builtin_interfaces.msg import Time  # noqa: E402
from geometry_msgs.msg import QuaternionStamped  # noqa: E402
from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField  # noqa: E402

from star_tracker.models.attitude_estimation import AttitudeSolution  # noqa: E402
from star_tracker.centroid import Spots  # noqa: E402
from star_tracker.track.rate import RateEstimate  # noqa: E402
from star_tracker.ros import convert  # noqa: E402

from fuzz_support import examples, some_float, uint32, valid_or_value_error  # noqa: E402

encodings = st.one_of(st.sampled_from(["mono8", "mono16", "8UC1", "16UC1", "rgb8", "bgr8", "32FC1", "", "MONO16"]),
                      st.text(max_size=12))


@st.composite
def image_messages(draw):
    """Mostly consistent mono images (small), with one or more fields then broken."""
    encoding = draw(st.sampled_from(["mono8", "mono16", "8UC1", "16UC1"]))
    item = 2 if "16" in encoding else 1
    height, width = draw(st.integers(1, 6)), draw(st.integers(1, 6))
    step = width * item + draw(st.integers(0, 3))
    msg = Image(height=height, width=width, encoding=encoding, step=step,
                is_bigendian=draw(st.integers(0, 1)))
    msg.data = draw(st.binary(min_size=step * height, max_size=step * height))
    for field in draw(st.lists(st.sampled_from(["height", "width", "step", "encoding", "data", "is_bigendian"]),
                               max_size=3, unique=True)):
        if field == "encoding":
            msg.encoding = draw(encodings)
        elif field == "data":
            msg.data = draw(st.binary(max_size=200))
        elif field == "is_bigendian":
            msg.is_bigendian = draw(st.integers(0, 255))
        else:
            setattr(msg, field, draw(uint32))
    return msg


@examples(1200)
@given(image_messages())
@pytest.mark.slow  # 1200 examples, ~5-8 s
def test_image_decoding_returns_the_image_or_a_value_error(msg):
    array = valid_or_value_error(convert.image_to_array, msg)
    if array is not None:
        assert array.shape == (msg.height, msg.width)
        assert array.dtype == (np.uint16 if "16" in msg.encoding else np.uint8)


@examples(300)
@given(hnp.arrays(st.sampled_from([np.uint8, np.uint16, np.dtype(">u2"), np.float32, np.int16]),
                  hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12)),
       st.integers(0, 2**31 * 10**9 - 1), st.booleans())
def test_image_encoding_round_trips_or_refuses_other_dtypes(array, stamp_ns, transposed):
    array = array.T if transposed else array  # non-contiguous input too
    msg = valid_or_value_error(convert.array_to_image, array, stamp_ns, "f")
    if array.dtype.kind != "u":
        assert msg is None
        return
    assert np.array_equal(convert.image_to_array(msg), array)
    assert convert.stamp_to_ns(msg.header.stamp) == stamp_ns


@st.composite
def camera_infos(draw):
    msg = CameraInfo(width=draw(uint32), height=draw(uint32))
    if draw(st.booleans()):  # a plausible K, perhaps slightly wrong
        f = draw(st.floats(1e-3, 1e6))
        k = [f, 0.0, draw(st.floats(-1e4, 1e4)), 0.0, f * draw(st.floats(0.5, 2.0)), draw(st.floats(-1e4, 1e4)),
             0.0, 0.0, 1.0]
        for i in draw(st.lists(st.integers(0, 8), max_size=2)):
            k[i] = draw(some_float)
    else:
        k = draw(st.lists(some_float, min_size=9, max_size=9))
    msg.k = k
    msg.d = draw(st.one_of(st.lists(st.floats(-0.5, 0.5), min_size=5, max_size=5),
                           st.lists(some_float, max_size=8)))
    msg.distortion_model = draw(st.sampled_from(["plumb_bob", "", "rational_polynomial", "equidistant", "x"]))
    return msg


@examples(1200)
@given(camera_infos())
@pytest.mark.slow  # 1200 examples, ~5-8 s
def test_camera_info_gives_a_usable_camera_or_a_value_error(msg):
    camera = valid_or_value_error(convert.info_to_camera, msg)
    if camera is not None:
        assert camera.width > 0 and camera.height > 0 and camera.fx > 0 and camera.fy > 0
        assert camera.half_diagonal_fov_rad < 0.5 * np.pi
        corners = np.array([[0.0, 0.0], [camera.width - 1.0, camera.height - 1.0]])
        assert np.all(np.isfinite(camera.pixel_to_ray(corners[:, 0], corners[:, 1])))


field_names = st.sampled_from([f.name for f in convert.SPOT_FIELDS] + ["z", "rgb", ""])


@st.composite
def spot_clouds(draw):
    """
    Spot clouds with the right layout and arbitrary bytes, or with a broken layout, sizes or data.

    Arbitrary bytes: any float32 bit pattern (NaN, inf, denormals).
    """
    n = draw(st.integers(0, 12))
    msg = PointCloud2(height=1, width=n, point_step=convert.SPOT_DTYPE.itemsize, fields=list(convert.SPOT_FIELDS),
                      is_bigendian=False, is_dense=True)
    msg.row_step = msg.point_step * n
    msg.data = draw(st.binary(min_size=n * msg.point_step, max_size=n * msg.point_step))
    broken = draw(st.lists(st.sampled_from(["fields", "point_step", "width", "height", "data", "bigendian"]),
                           max_size=2, unique=True))
    for field in broken:
        if field == "fields":
            msg.fields = draw(st.lists(st.builds(PointField, name=field_names, offset=st.integers(0, 64),
                                                 datatype=st.integers(0, 10), count=st.integers(0, 3)), max_size=11))
        elif field == "data":
            msg.data = draw(st.binary(max_size=500))
        elif field == "bigendian":
            msg.is_bigendian = True
        else:
            setattr(msg, field, draw(uint32))
    return msg


@examples(1200)
@given(spot_clouds())
@pytest.mark.slow  # 1200 examples, ~5-8 s
def test_spot_clouds_decode_or_raise_and_invalid_spots_are_dropped(msg):
    spots = valid_or_value_error(convert.cloud_to_spots, msg, 1024, 1024)
    if spots is None:
        return
    assert len(spots) == msg.width * msg.height
    kept, dropped = convert.drop_invalid_spots(spots)
    assert len(kept) + dropped == len(spots)
    for values in (kept.x, kept.y, kept.flux, kept.cov):
        assert np.all(np.isfinite(values))
    assert np.all(kept.cov[:, 0, 0] <= convert.MAX_SPOT_SIGMA_PX ** 2) and np.all(kept.cov[:, 1, 1] >= 0)


finite32 = st.floats(-1e6, 1e6, width=32)


@examples(300)
@given(st.lists(st.tuples(finite32, finite32, finite32, finite32, finite32, finite32, finite32,
                          st.integers(0, 2**32 - 1), finite32, finite32), max_size=20),
       st.integers(-2**62, 2**62))
@pytest.mark.slow  # ~5 s
def test_spots_survive_the_round_trip_bit_for_bit(rows, stamp_ns):
    n = len(rows)
    r = np.array(rows, dtype=object).reshape(n, 10)
    col = lambda i: r[:, i].astype(float) if n else np.zeros(0)  # noqa: E731
    cov = np.stack([np.stack([col(4), col(5)], -1), np.stack([col(5), col(6)], -1)], -2) if n else np.zeros((0, 2, 2))
    spots = Spots(col(0), col(1), col(2), col(3), cov, col(7).astype(np.uint32), np.zeros(n, np.int32), np.zeros(n),
                  1024, 1024, streak_length=col(8), streak_angle=col(9))
    msg = valid_or_value_error(convert.spots_to_cloud, spots, stamp_ns, "f")
    if msg is None:  # only a stamp beyond int32 seconds is refused
        assert not -2**31 <= stamp_ns // 10**9 < 2**31
        return
    back = convert.cloud_to_spots(msg, 1024, 1024)
    for name in ("x", "y", "flux", "snr", "cov", "flags", "streak_length", "streak_angle"):
        assert np.array_equal(getattr(back, name), getattr(spots, name)), name


@examples(600)
@given(st.lists(some_float, min_size=4, max_size=4), st.integers(-2**70, 2**70),
       hnp.arrays(np.float64, (3, 3), elements=some_float), st.integers(-2**70, 2**70))
def test_attitude_and_rate_messages_encode_anything_or_refuse_the_stamp(q, stamp_ns, cov, time_ns):
    in_range = -2**31 <= stamp_ns // 10**9 < 2**31
    msg = valid_or_value_error(convert.quaternion_msg, np.array(q), stamp_ns)
    assert (msg is not None) == in_range
    if msg is not None:
        assert np.array_equal(convert.quaternion_from_msg(msg), np.array(q), equal_nan=True)
        assert convert.stamp_to_ns(msg.header.stamp) == stamp_ns
    rot = np.eye(3)
    pose = valid_or_value_error(convert.pose_with_covariance_msg, AttitudeSolution(np.array(q), rot, cov, 0.0),
                                stamp_ns)
    assert (pose is not None) == in_range
    if pose is not None:  # the quaternion as given, the covariance in the rotation block
        o = pose.pose.pose.orientation
        assert np.array_equal([o.x, o.y, o.z, o.w], q, equal_nan=True)
        assert np.array_equal(np.reshape(pose.pose.covariance, (6, 6))[3:, 3:], cov, equal_nan=True)
    vector = valid_or_value_error(convert.vector3_msg, np.array(q[:3]), stamp_ns, "f")
    assert (vector is not None) == in_range
    if vector is not None:
        assert np.array_equal([vector.vector.x, vector.vector.y, vector.vector.z], q[:3], equal_nan=True)
    rate = valid_or_value_error(convert.rate_with_covariance_msg, RateEstimate(time_ns, np.array(q[:3]), cov, 2), "f")
    assert (rate is not None) == (-2**31 <= time_ns // 10**9 < 2**31)
    if rate is not None:
        angular = rate.twist.twist.angular
        assert np.array_equal([angular.x, angular.y, angular.z], q[:3], equal_nan=True)
        assert np.array_equal(np.reshape(rate.twist.covariance, (6, 6))[3:, 3:], cov, equal_nan=True)
        assert convert.stamp_to_ns(rate.header.stamp) == time_ns


@examples(300)
@given(st.integers(-2**31, 2**31 - 1), st.integers(0, 2**32 - 1))
def test_any_received_stamp_converts(sec, nanosec):
    stamp = QuaternionStamped().header.stamp
    stamp.sec, stamp.nanosec = sec, nanosec
    assert convert.stamp_to_ns(stamp) == sec * 10**9 + nanosec
    if nanosec < 10**9:  # a well-formed stamp survives the way back
        assert convert.ns_to_stamp(convert.stamp_to_ns(stamp)) == Time(sec=sec, nanosec=nanosec)
