# SPDX-License-Identifier: Apache-2.0
"""
Message <-> core-record conversion. Layouts are documented in msg_docs/.

Raises ValueError with a message naming the problem for any malformed message (and never
another exception type: test/ros/test_fuzz.py checks that on generated garbage).
"""
from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from scipy.spatial import cKDTree
from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped, TwistWithCovarianceStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField
from std_msgs.msg import Header

from ..models.attitude import (matrix_to_quaternion, matrix_to_rotation_vector, quaternion_to_matrix,
                               rotation_vector_to_matrix)
from ..models.attitude_estimation import AttitudeSolution
from ..models.matrix_checks import covariance_problem
from ..models.camera import CameraModel
from ..centroid import Spots
from ..identify.base import Identification, direction_covariance

ICRS_FRAME = "icrs"
OPTICAL_FRAME = "star_tracker_optical"
MAX_IMAGE_PIXELS = 64 * 1024 * 1024
MAX_CLOUD_POINTS = 100_000  # the centroider's largest max_spots
MAX_SPOT_SIGMA_PX = 20.0  # a spot 1-sigma beyond this is no measurement (real ones: < 6 px, streaks included)
SPOT_MARGIN_PX = 10.0  # spots this far outside the image are not from this camera
MIN_SPOT_SEPARATION_PX = 0.01  # two spots closer than this are one measurement reported twice

_IMAGE_DTYPES = {"mono8": np.uint8, "8UC1": np.uint8, "mono16": np.uint16, "16UC1": np.uint16}


# ----------------------------------------------------------------------------- time
def stamp_to_ns(stamp: Time) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    if not -2**31 <= sec < 2**31:
        raise ValueError(f"stamp {ns} ns does not fit builtin_interfaces/Time (int32 seconds)")
    return Time(sec=int(sec), nanosec=int(nanosec))


# ----------------------------------------------------------------------------- image
def image_to_array(msg: Image) -> np.ndarray:
    """
    Return a mono8/mono16 Image as a (height, width) array in native byte order.

    A view of the message's data where its layout allows (rows without padding, native byte
    order): it keeps the message's buffer alive and is read-only when that is (bytes).
    """
    dtype = _IMAGE_DTYPES.get(msg.encoding)
    if dtype is None:
        raise ValueError(f"unsupported image encoding {msg.encoding!r}; expected one of {sorted(_IMAGE_DTYPES)}")
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        raise ValueError(f"empty image {width}x{height}")
    if height * width > MAX_IMAGE_PIXELS:
        raise ValueError(f"image {width}x{height} exceeds the {MAX_IMAGE_PIXELS}-pixel limit")
    item = np.dtype(dtype).itemsize
    if step < width * item:
        raise ValueError(f"step {step} < width*bytes_per_pixel {width * item}")
    data = msg.data
    try:  # a view, not a copy: rclpy's array.array, bytes, a memoryview of a raw message (image_cdr.py)
        buffer = np.frombuffer(data, dtype=np.uint8)
    except (TypeError, ValueError):  # a list of ints
        buffer = np.frombuffer(bytes(data), dtype=np.uint8)
    if buffer.size != step * height:
        raise ValueError(f"data size {buffer.size} != step*height {step * height}")
    rows = buffer.reshape(height, step)[:, : width * item]
    array = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<"))
    return array.astype(dtype, copy=False)


def array_to_image(array: np.ndarray, stamp_ns: int, frame_id: str) -> Image:
    array = np.asarray(array)
    if array.ndim != 2 or array.dtype.kind != "u" or array.dtype.itemsize not in (1, 2):
        raise ValueError(f"expected a 2-D uint8/uint16 array (either byte order), got {array.dtype} {array.shape}")
    encoding = "mono16" if array.dtype.itemsize == 2 else "mono8"
    array = np.ascontiguousarray(array.astype(array.dtype.newbyteorder("<"), copy=False))
    msg = Image()
    msg.header = Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)
    msg.height, msg.width = int(array.shape[0]), int(array.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = int(array.shape[1] * array.itemsize)
    msg.data = array.tobytes()
    return msg


# ----------------------------------------------------------------------------- camera info
def camera_to_info(camera: CameraModel, stamp_ns: int, frame_id: str) -> CameraInfo:
    msg = CameraInfo()
    msg.header = Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)
    msg.width, msg.height = camera.width, camera.height
    msg.distortion_model = "plumb_bob"
    msg.d = [float(d) for d in camera.distortion]
    msg.k = [float(v) for v in camera.intrinsic_matrix().ravel()]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.p = [camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def info_to_camera(msg: CameraInfo) -> CameraModel:
    """Return the CameraModel from K and D (plumb_bob or empty D = no distortion)."""
    k = np.asarray(msg.k, dtype=float)
    if k.size != 9 or not np.all(np.isfinite(k)):
        raise ValueError(f"CameraInfo K must be 9 finite values, got {list(k)}")
    if int(msg.width) * int(msg.height) > MAX_IMAGE_PIXELS:
        raise ValueError(f"CameraInfo size {msg.width}x{msg.height} exceeds the {MAX_IMAGE_PIXELS}-pixel limit")
    d = list(msg.d)
    if msg.distortion_model not in ("plumb_bob", "") and d:
        raise ValueError(f"unsupported distortion model {msg.distortion_model!r}; expected plumb_bob")
    if len(d) not in (0, 5):
        raise ValueError(f"plumb_bob needs 5 distortion coefficients, got {len(d)}")
    d = tuple(float(x) for x in (d or [0.0] * 5))
    camera = CameraModel(int(msg.width), int(msg.height), k[0], k[4], k[2], k[5], d)
    # The border pixels must see directions in front of the lens that project back onto them:
    # a wild distortion (not invertible there) would send the identifier stars in wrong places.
    w, h = camera.width - 1.0, camera.height - 1.0
    u = np.array([0.0, w, 0.0, w, 0.5 * w, 0.5 * w, 0.0, w])
    v = np.array([0.0, 0.0, h, h, 0.0, h, 0.5 * h, 0.5 * h])
    with np.errstate(all="ignore"):
        rays = camera.pixel_to_ray(u, v)
        back_u, back_v, _ = camera.project(rays)
        error = np.hypot(back_u - u, back_v - v)
    if not (np.all(np.isfinite(rays)) and np.all(rays[:, 2] > 1e-6) and np.all(error < 0.05)):
        raise ValueError(f"CameraInfo describes no usable field of view (distortion {list(d)} not invertible "
                         "at the image border)")
    return camera


# ----------------------------------------------------------------------------- point clouds
def _fields(spec: list[tuple[str, int]]) -> tuple[list[PointField], np.dtype]:
    kinds = {PointField.FLOAT32: "<f4", PointField.UINT32: "<u4", PointField.FLOAT64: "<f8"}
    fields, names, formats, offsets, offset = [], [], [], [], 0
    for name, datatype in spec:
        fields.append(PointField(name=name, offset=offset, datatype=datatype, count=1))
        names.append(name)
        formats.append(kinds[datatype])
        offsets.append(offset)
        offset += np.dtype(kinds[datatype]).itemsize
    return fields, np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": offset})


SPOT_FIELDS, SPOT_DTYPE = _fields([
    ("x", PointField.FLOAT32), ("y", PointField.FLOAT32), ("flux", PointField.FLOAT32),
    ("snr", PointField.FLOAT32), ("cov_xx", PointField.FLOAT32), ("cov_xy", PointField.FLOAT32),
    ("cov_yy", PointField.FLOAT32), ("flags", PointField.UINT32), ("streak_length", PointField.FLOAT32),
    ("streak_angle", PointField.FLOAT32)])

MATCH_FIELDS, MATCH_DTYPE = _fields([
    ("x", PointField.FLOAT32), ("y", PointField.FLOAT32), ("z", PointField.FLOAT32),
    ("hip_id", PointField.UINT32), ("pixel_x", PointField.FLOAT32), ("pixel_y", PointField.FLOAT32),
    ("residual", PointField.FLOAT32), ("magnitude", PointField.FLOAT32), ("sigma", PointField.FLOAT32)])

TRUTH_OBJECT_FIELDS, TRUTH_OBJECT_DTYPE = _fields([
    ("hip_id", PointField.UINT32), ("pixel_x", PointField.FLOAT32), ("pixel_y", PointField.FLOAT32),
    ("electrons", PointField.FLOAT32), ("kind", PointField.UINT32)])


def records_to_cloud(records: np.ndarray, fields: list[PointField], stamp_ns: int, frame_id: str) -> PointCloud2:
    msg = PointCloud2()
    msg.header = Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)
    msg.height = 1
    msg.width = int(records.size)
    # Copies: the message must not share (and let a consumer alter) the module's layout constants.
    msg.fields = [PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in fields]
    msg.is_bigendian = False
    msg.point_step = int(records.dtype.itemsize)
    msg.row_step = msg.point_step * msg.width
    msg.is_dense = True
    msg.data = records.tobytes()
    return msg


def cloud_to_records(msg: PointCloud2, fields: list[PointField], dtype: np.dtype) -> np.ndarray:
    """Decode a PointCloud2 whose layout must equal `fields` (name, offset, datatype)."""
    got = [(f.name, int(f.offset), int(f.datatype), int(f.count)) for f in msg.fields]
    want = [(f.name, f.offset, f.datatype, 1) for f in fields]
    if got != want:
        raise ValueError(f"unexpected PointCloud2 layout {got}; expected {want}")
    if msg.is_bigendian:
        raise ValueError("big-endian PointCloud2 is not supported")
    if int(msg.point_step) != dtype.itemsize:
        raise ValueError(f"point_step {msg.point_step} != {dtype.itemsize}")
    count = int(msg.width) * int(msg.height)
    if count > MAX_CLOUD_POINTS:
        raise ValueError(f"PointCloud2 with {count} points exceeds the {MAX_CLOUD_POINTS}-point limit")
    data = msg.data
    raw = data.tobytes() if hasattr(data, "tobytes") else bytes(data)
    if len(raw) != count * dtype.itemsize:
        raise ValueError(f"PointCloud2 data has {len(raw)} bytes, expected {count * dtype.itemsize}")
    return np.frombuffer(raw, dtype=dtype)


def spots_to_cloud(spots: Spots, stamp_ns: int, frame_id: str) -> PointCloud2:
    rec = np.zeros(len(spots), SPOT_DTYPE)
    rec["x"], rec["y"], rec["flux"], rec["snr"] = spots.x, spots.y, spots.flux, spots.snr
    rec["cov_xx"], rec["cov_xy"], rec["cov_yy"] = spots.cov[:, 0, 0], spots.cov[:, 0, 1], spots.cov[:, 1, 1]
    rec["flags"] = spots.flags
    rec["streak_length"], rec["streak_angle"] = spots.streak_length, spots.streak_angle
    return records_to_cloud(rec, SPOT_FIELDS, stamp_ns, frame_id)


def cloud_to_spots(msg: PointCloud2, width: int, height: int) -> Spots:
    """Spots from a `spots` cloud, values as received (NaN included: see drop_invalid_spots)."""
    rec = cloud_to_records(msg, SPOT_FIELDS, SPOT_DTYPE)
    n = rec.size
    cov = np.empty((n, 2, 2))
    with np.errstate(invalid="ignore"):  # signalling-NaN bit patterns warn when widened
        cov[:, 0, 0] = rec["cov_xx"]
        cov[:, 1, 1] = rec["cov_yy"]
        cov[:, 0, 1] = cov[:, 1, 0] = rec["cov_xy"]
        return Spots(x=rec["x"].astype(float), y=rec["y"].astype(float), flux=rec["flux"].astype(float),
                     snr=rec["snr"].astype(float), cov=cov, flags=rec["flags"].astype(np.uint32),
                     area=np.zeros(n, np.int32), peak=np.zeros(n), width=width, height=height,
                     streak_length=rec["streak_length"].astype(float), streak_angle=rec["streak_angle"].astype(float))


def drop_invalid_spots(spots: Spots) -> tuple[Spots, int]:
    """
    Return the spots a real measurement can produce, and how many others were dropped.

    Position, flux and covariance finite, variances in [0, MAX_SPOT_SIGMA_PX^2] px^2,
    position within SPOT_MARGIN_PX of the image, and no two closer than
    MIN_SPOT_SEPARATION_PX (the first, brightest, is kept). NaN/inf from a faulty producer
    would otherwise reach the identifier, whose tolerances grow with the covariance (and its
    run time with them); coincident spots make its pattern kernels divide by zero
    (docs/RELIABILITY.md, known defects).
    """
    with np.errstate(invalid="ignore"):
        var_x, var_y = spots.cov[:, 0, 0], spots.cov[:, 1, 1]
        limit = MAX_SPOT_SIGMA_PX ** 2
        ok = (np.isfinite(spots.x) & np.isfinite(spots.y) & np.isfinite(spots.flux)
              & np.all(np.isfinite(spots.cov.reshape(-1, 4)), axis=1)
              & (var_x >= 0) & (var_x <= limit) & (var_y >= 0) & (var_y <= limit)
              & (spots.x >= -0.5 - SPOT_MARGIN_PX) & (spots.x <= spots.width - 0.5 + SPOT_MARGIN_PX)
              & (spots.y >= -0.5 - SPOT_MARGIN_PX) & (spots.y <= spots.height - 0.5 + SPOT_MARGIN_PX))
    valid = np.flatnonzero(ok)
    if valid.size > 1:  # of two coincident spots, the later (fainter) goes
        close = cKDTree(np.stack([spots.x[valid], spots.y[valid]], axis=1)).query_pairs(
            MIN_SPOT_SEPARATION_PX, output_type="ndarray")
        if close.size:
            ok[valid[close.max(axis=1)]] = False
    dropped = int(ok.size - np.count_nonzero(ok))
    return (spots if dropped == 0 else spots.take(ok)), dropped


def identification_to_cloud(result: Identification, spots: Spots, magnitudes: np.ndarray,
                            stamp_ns: int, frame_id: str, camera: CameraModel) -> PointCloud2:
    """
    Return the `matched_stars` cloud of a solved identification (msg_docs/matched_stars.md).

    `spots` are the identified ones (result.spot_index points into them) and `camera` the model
    that turned them into rays; each star's `sigma` is matched_star_sigma's.
    """
    rec = np.zeros(result.hip.size, MATCH_DTYPE)
    rec["x"], rec["y"], rec["z"] = result.star_vectors.T
    rec["hip_id"] = result.hip
    rec["pixel_x"] = spots.x[result.spot_index]
    rec["pixel_y"] = spots.y[result.spot_index]
    rec["residual"] = result.residual_rad
    rec["magnitude"] = magnitudes
    rec["sigma"] = matched_star_sigma(camera, rec["pixel_x"], rec["pixel_y"], spots.cov[result.spot_index])
    return records_to_cloud(rec, MATCH_FIELDS, stamp_ns, frame_id)


def matched_star_sigma(camera: CameraModel, x: np.ndarray, y: np.ndarray, cov_px: np.ndarray) -> np.ndarray:
    """
    Return the 1-sigma direction error [rad] of the rays of spots at (x, y) [px], each along its worst direction.

    sqrt of the largest eigenvalue of J C J^T: C the spot's pixel covariance cov_px (N, 2, 2)
    [px^2] as the identifier's final fit weights it (identify.base.sanitized_covariance), J the
    camera's d ray / d pixel there. One number per star, conservative for a streak (its error
    along the smear).
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if x.size == 0:
        return np.zeros(0)
    return np.sqrt(np.linalg.eigvalsh(direction_covariance(camera, x, y, cov_px))[:, -1])


# ----------------------------------------------------------------------------- orbit
def odometry_msg(position_m, velocity_m_s, stamp_ns: int, frame_id: str = "gcrs") -> Odometry:
    """
    Return the spacecraft's state as nav_msgs/Odometry (msg_docs/odometry.md).

    Geocentric position [m] and velocity [m/s] on GCRS axes: header and child frame `frame_id`
    (so the twist is on those axes too); orientation identity; covariances unknown (-1).
    """
    msg = Odometry()
    msg.header = Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)
    msg.child_frame_id = frame_id
    msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z = (float(x) for x in position_m)
    msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.linear.z = (float(x) for x in velocity_m_s)
    unknown = np.zeros(36)
    unknown[[0, 7, 14, 21, 28, 35]] = -1.0
    msg.pose.covariance = unknown.tolist()
    msg.twist.covariance = unknown.tolist()
    return msg


# ----------------------------------------------------------------------------- attitude
def quaternion_msg(q_xyzw: np.ndarray, stamp_ns: int, frame_id: str = ICRS_FRAME) -> QuaternionStamped:
    msg = QuaternionStamped()
    msg.header = Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)
    msg.quaternion.x, msg.quaternion.y, msg.quaternion.z, msg.quaternion.w = (float(v) for v in q_xyzw)
    return msg


def quaternion_from_msg(msg: QuaternionStamped) -> np.ndarray:
    q = msg.quaternion
    return np.array([q.x, q.y, q.z, q.w])


def pose_with_covariance_msg(solution: AttitudeSolution, stamp_ns: int,
                             frame_id: str = ICRS_FRAME) -> PoseWithCovarianceStamped:
    """
    Orientation + 6x6 covariance.

    The position block is unknown (-1 on its diagonal); the rotation block is the
    sensor-frame small-angle attitude error covariance [rad^2].
    """
    msg = PoseWithCovarianceStamped()
    msg.header = Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in solution.quaternion)
    msg.pose.covariance = _rotation_block_covariance(solution.covariance)
    return msg


def path_offset_msg(offset_rad: np.ndarray, covariance: np.ndarray, stamp_ns: int,
                    frame_id: str) -> PoseWithCovarianceStamped:
    """
    Return a frame's offset from its exposure-average attitude to mid-exposure (smear_aid/exposure_path_offset).

    Orientation: exp([offset x]) (R_mid = R_mean exp([offset x]), in the sensor frame
    `frame_id`); the rotation block of the covariance: the offset's [rad^2]; the position
    block unknown (-1 on its diagonal).
    """
    msg = PoseWithCovarianceStamped()
    msg.header = Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in matrix_to_quaternion(rotation_vector_to_matrix(offset_rad)))
    msg.pose.covariance = _rotation_block_covariance(covariance)
    return msg


def path_offset_from_msg(msg) -> tuple[np.ndarray, np.ndarray] | None:
    """
    Return (offset [rad] (3,), covariance [rad^2] (3, 3)) of a path_offset_msg, or None when malformed.

    Malformed: a non-finite or non-unit quaternion (beyond 1e-3), a rotation block that
    matrix_checks.covariance_problem refuses (semi-definite allowed). Duck-typed
    (pose.pose.orientation, pose.covariance).
    """
    o = msg.pose.pose.orientation
    q = np.array([o.x, o.y, o.z, o.w], float)
    if len(msg.pose.covariance) != 36 or not (np.all(np.isfinite(q)) and abs(np.linalg.norm(q) - 1.0) <= 1e-3):
        return None
    block = np.asarray(msg.pose.covariance, float).reshape(6, 6)[3:, 3:]
    if covariance_problem(block, definite=False) is not None:
        return None
    return matrix_to_rotation_vector(quaternion_to_matrix(q / np.linalg.norm(q))), block


def _rotation_block_covariance(block: np.ndarray) -> list[float]:
    """
    Row-major 6x6 covariance of a pose/twist whose angular part is `block` (3x3).

    The linear part is unknown (-1 on its diagonal, as REP 145 suggests).
    """
    cov = np.zeros((6, 6))
    cov[0, 0] = cov[1, 1] = cov[2, 2] = -1.0
    cov[3:, 3:] = block
    return [float(v) for v in cov.ravel()]


def vector3_msg(vector: np.ndarray, stamp_ns: int, frame_id: str) -> Vector3Stamped:
    msg = Vector3Stamped()
    msg.header = Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)
    msg.vector.x, msg.vector.y, msg.vector.z = (float(v) for v in vector)
    return msg


def rate_with_covariance_msg(rate, frame_id: str) -> TwistWithCovarianceStamped:
    """
    Return a TwistWithCovarianceStamped of a body rate (sensor frame, rad/s) and its covariance.

    The 3x3 covariance [rad^2/s^2] fills the angular block; the linear part is unknown (-1 on
    its diagonal).
    """
    msg = TwistWithCovarianceStamped()
    msg.header = Header(stamp=ns_to_stamp(rate.stamp_ns), frame_id=frame_id)
    msg.twist.twist.angular.x, msg.twist.twist.angular.y, msg.twist.twist.angular.z = (
        float(v) for v in rate.angular_velocity)
    msg.twist.covariance = _rotation_block_covariance(rate.covariance)
    return msg
