# SPDX-License-Identifier: Apache-2.0
"""
What the bag recorder and player share on the ROS side.

Message classes by type name and QoS conversions between rclpy and rosbag2 metadata
(rosbags' Qos records).
"""
from __future__ import annotations

import importlib

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from ..bags import BagError

RECORD_QUEUE_DEPTH = 50  # 5 s at 10 Hz: a recorder stalled that long (disk, CPU steal) loses nothing
PLAY_QUEUE_DEPTH = 10  # rosbag2's playback depth; the camera_simulator's own image depth


def message_class(type_name: str) -> type:
    """Return the Python class of 'package/msg/Name' (needs the package's rclpy bindings installed)."""
    parts = type_name.split("/")
    if len(parts) != 3 or not all(parts):
        raise BagError(f"message type {type_name!r} is not of the form package/msg/Name")
    package, kind, name = parts
    try:
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ImportError, AttributeError):
        raise BagError(f"message type {type_name} is not installed here (no Python module {package}.{kind} "
                       f"with {name})") from None


def _enum(cls, value: int, unknown):
    try:
        return cls(int(value))
    except ValueError:
        return unknown


def _time(duration: Duration) -> QosTime:
    sec, nsec = divmod(int(duration.nanoseconds), 1_000_000_000)  # infinite: 9223372036 s 854775807 ns, as Jazzy
    return QosTime(sec, nsec)


def offered_qos(profile: QoSProfile) -> Qos:
    """
    Return a publisher's QoS (from get_publishers_info_by_topic) as rosbag2 records it.

    Fast DDS does not report a remote writer's history and depth: they are recorded as
    unknown / 0, as `ros2 bag record` does.
    """
    return Qos(
        _enum(QosHistory, profile.history.value, QosHistory.UNKNOWN), int(profile.depth),
        _enum(QosReliability, profile.reliability.value, QosReliability.UNKNOWN),
        _enum(QosDurability, profile.durability.value, QosDurability.UNKNOWN),
        _time(profile.deadline), _time(profile.lifespan),
        _enum(QosLiveliness, profile.liveliness.value, QosLiveliness.UNKNOWN),
        _time(profile.liveliness_lease_duration), bool(profile.avoid_ros_namespace_conventions))


def subscription_qos(offers: list[QoSProfile], depth: int) -> QoSProfile:
    """
    Return the subscription QoS for a topic's publishers, as rosbag2 adapts it.

    Reliable only if every publisher is (a reliable reader does not match a best-effort
    writer), transient local only if every publisher is; keep last `depth`.
    """
    reliable = bool(offers) and all(p.reliability == ReliabilityPolicy.RELIABLE for p in offers)
    latched = bool(offers) and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offers)
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def playback_qos(recorded: tuple | list, depth: int = PLAY_QUEUE_DEPTH) -> QoSProfile:
    """
    Return the QoS to offer when playing a topic.

    The recorded publishers' reliability and durability when they all agree (rosbag2's
    rule), else reliable + volatile, which every subscriber matches; keep last `depth`.
    """
    reliability, durability = ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE
    if recorded and len({(q.reliability, q.durability) for q in recorded}) == 1:
        if recorded[0].reliability == QosReliability.BEST_EFFORT:
            reliability = ReliabilityPolicy.BEST_EFFORT
        if recorded[0].durability == QosDurability.TRANSIENT_LOCAL:
            durability = DurabilityPolicy.TRANSIENT_LOCAL
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST, reliability=reliability, durability=durability)


def qos_text(profile: QoSProfile) -> str:
    return f"{profile.reliability.name.lower()}, {profile.durability.name.lower()}, keep last {profile.depth}"
