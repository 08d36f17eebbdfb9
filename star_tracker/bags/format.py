# SPDX-License-Identifier: Apache-2.0
"""
What every bag module shares.

The topics of a star_tracker run, the rosbag2 format constants, BagError, the ROS 2 Jazzy
type store, and the header stamp of a serialized message. Times are integer nanoseconds.
"""
from __future__ import annotations

import struct
from functools import lru_cache

# The topics of a star_tracker run (msg_docs/README.md), as absolute names in the root namespace.
CAMERA_TOPICS = ("/image_raw", "/camera_info")
TRUTH_TOPICS = ("/truth/attitude", "/truth/angular_velocity", "/truth/objects")
OUTPUT_TOPICS = ("/spots", "/smear_aid/angular_velocity", "/smear_aid/exposure_path_offset",
                 "/smear_aid/angular_acceleration",
                 "/attitude", "/attitude_with_covariance", "/angular_velocity",
                 "/angular_velocity_with_covariance", "/matched_stars")
DEFAULT_RECORD_TOPICS = CAMERA_TOPICS + TRUTH_TOPICS + OUTPUT_TOPICS

STORAGES = ("sqlite3", "mcap")
BAG_VERSION = 9  # rosbag2 metadata version of ROS 2 Jazzy
IMAGE_TYPE = "sensor_msgs/msg/Image"
# What the centroider accepts (star_tracker.ros.convert.image_to_array), bytes per pixel.
IMAGE_ENCODINGS = {"mono8": 1, "8UC1": 1, "mono16": 2, "16UC1": 2}


class BagError(Exception):
    """A bag cannot be opened, read, written or recovered; the message says why."""


@lru_cache(maxsize=1)
def typestore():
    """Return the ROS 2 Jazzy message definitions shipped with rosbags (no ROS install needed)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def absolute_topic(name: str) -> str:
    """'image_raw' -> '/image_raw' (topics recorded from the root namespace)."""
    name = name.strip()
    if not name or name == "/":
        raise BagError(f"invalid topic name {name!r}")
    return name if name.startswith("/") else "/" + name


def header_stamp_ns(data: bytes | memoryview) -> int:
    """
    Return the header stamp [ns] of a serialized message whose first field is a std_msgs/Header (every stamped message).

    Read from the CDR bytes without deserializing the rest.
    """
    if len(data) < 12:
        raise BagError(f"serialized message of {len(data)} bytes is too short for a header")
    order = "<" if bytes(data[1:2]) in (b"\x01", b"\x03") else ">"  # CDR_LE / PL_CDR_LE
    sec, nanosec = struct.unpack_from(order + "iI", data, 4)
    return sec * 1_000_000_000 + nanosec
