# SPDX-License-Identifier: Apache-2.0
"""
Rosbag2 bags (sqlite3 or MCAP storage) without ROS.

Open and validate, list topics, iterate raw (serialized CDR) messages, write, and recover a
bag whose recording was killed.

Built on the `rosbags` library, so every bag written here has the standard rosbag2 layout
(a directory with metadata.yaml, version 9, and one .db3 or .mcap file) that `ros2 bag
info/play` read. Every problem raises BagError with a message naming the bag, the file or
topic and what is wrong; nothing here imports rclpy. Times are integer nanoseconds.

Modules: format (topics, constants, BagError, type store), reader (BagReader, BagInfo),
validate (check_bag, image_problem), writer (BagWriter), recovery (reindex) with
mcap_salvage (unfinished MCAP files).
"""
from .format import (BAG_VERSION, CAMERA_TOPICS, DEFAULT_RECORD_TOPICS, IMAGE_ENCODINGS, IMAGE_TYPE, OUTPUT_TOPICS,
                     STORAGES, TRUTH_TOPICS, BagError, absolute_topic, header_stamp_ns, typestore)
from .reader import BagInfo, BagReader, TopicInfo
from .recovery import reindex
from .validate import check_bag, image_problem
from .writer import BagWriter, message_definition

__all__ = ["BAG_VERSION", "CAMERA_TOPICS", "DEFAULT_RECORD_TOPICS", "IMAGE_ENCODINGS", "IMAGE_TYPE", "OUTPUT_TOPICS",
           "STORAGES", "TRUTH_TOPICS", "BagError", "BagInfo", "BagReader", "BagWriter", "TopicInfo", "absolute_topic",
           "check_bag", "header_stamp_ns", "image_problem", "message_definition", "reindex", "typestore"]
