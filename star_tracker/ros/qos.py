"""Quality-of-service profiles of the star tracker's topics: reliable results, best-effort
sensor data with a queue deep enough to ride out a short stall."""
from __future__ import annotations

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

RESULT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)


def sensor_qos(depth: int) -> QoSProfile:
    """Sensor-data profile (best effort, volatile) with a queue of `depth`. Deeper than the
    profile's 5 so that a process stalled for a moment (CPU steal on a shared host, a slow
    frame) catches up instead of losing what arrived meanwhile; Fast DDS sends large samples
    asynchronously, so writers need the depth as well as readers."""
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                      durability=qos_profile_sensor_data.durability)


IMAGE_QOS = sensor_qos(10)  # image_raw, camera_info: 1 s of frames at 10 Hz (~20 MiB at most)
SPOTS_QOS = sensor_qos(20)
