# SPDX-License-Identifier: Apache-2.0
"""
Quality-of-service profiles of the star tracker's topics, and `overridable()`.

The arguments that make a publisher's or subscription's QoS settable by parameters.

Outputs: reliable results; best-effort sensor data (images, spots) with queues deep enough to
ride out a short stall. Inputs from sensors (a gyro, external truth) are subscribed best
effort, the profile sensor drivers publish with: a best-effort subscription matches best-effort
and reliable publishers alike, a reliable one only reliable publishers (silently).

Every publisher and subscription made with `**overridable(PROFILE)` declares the read-only
parameters `qos_overrides.<resolved topic>.<publisher|subscription>.<policy>` (policy:
history, depth, reliability, durability; rclpy's QoSOverridingOptions), e.g.
`-p qos_overrides./angular_velocity.subscription.reliability:=reliable`. The topic is the
resolved name: namespace and remapping included.
"""
from __future__ import annotations

import copy

from rcl_interfaces.msg import SetParametersResult
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions, QoSPolicyKind

RESULT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
DIAGNOSTICS_QOS = QoSProfile(depth=10)  # rclpy's default (reliable, volatile), as diagnostic_updater offers


def sensor_qos(depth: int) -> QoSProfile:
    """
    Sensor-data profile (best effort, volatile) with a queue of `depth`.

    Deeper than the profile's 5 so that a process stalled for a moment (CPU steal on a
    shared host, a slow frame) catches up instead of losing what arrived meanwhile; Fast DDS
    sends large samples asynchronously, so writers need the depth as well as readers.
    """
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                      durability=qos_profile_sensor_data.durability)


IMAGE_QOS = sensor_qos(10)  # image_raw, camera_info: 1 s of frames at 10 Hz (~20 MiB at most)
SPOTS_QOS = sensor_qos(20)
# Subscriptions to sensor inputs: a gyro (angular_velocity, imu) sends 100-1000 Hz bursts and only
# recent samples matter; external truth (truth_in/*) is paired by stamp, so a deeper queue.
RATE_INPUT_QOS = sensor_qos(50)
TRUTH_INPUT_QOS = sensor_qos(100)

OVERRIDABLE_POLICIES = (QoSPolicyKind.HISTORY, QoSPolicyKind.DEPTH, QoSPolicyKind.RELIABILITY,
                        QoSPolicyKind.DURABILITY)


def _check_overrides(qos: QoSProfile) -> SetParametersResult:
    """
    Check that a keep-last queue holds at least one message.

    Depth 0 is rejected by the middleware with a less clear message, or not at all.
    """
    if qos.history == HistoryPolicy.KEEP_LAST and qos.depth < 1:
        return SetParametersResult(successful=False, reason=f"depth {qos.depth} must be >= 1 with history keep_last")
    if qos.durability == DurabilityPolicy.UNKNOWN or qos.reliability == ReliabilityPolicy.UNKNOWN:
        return SetParametersResult(successful=False, reason="reliability and durability must be known policies")
    return SetParametersResult(successful=True)


def overridable(profile: QoSProfile) -> dict:
    """
    Keyword arguments for create_publisher/create_subscription.

    A copy of `profile` (rclpy writes the overrides into the profile it is given) and the
    overriding options. A bad override stops the node at startup with the parameter's name
    (rclpy's InvalidQosOverridesError or RuntimeError).
    """
    return {"qos_profile": copy.copy(profile),
            "qos_overriding_options": QoSOverridingOptions(OVERRIDABLE_POLICIES, callback=_check_overrides)}


def is_qos_override(parameter_name: str) -> bool:
    """Return True for the parameters rclpy declares for overridable QoS (read-only, set at startup)."""
    return parameter_name.startswith("qos_overrides.")
