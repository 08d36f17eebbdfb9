# SPDX-License-Identifier: Apache-2.0
"""
The centroider's parameters, each declared once (ROS-free).

CentroidConfig's fields (their spec is the dataclass field metadata, centroid/config.py) and
the node's own, in the order the node declares them and config/star_tracker.yaml lists them.
"""
from __future__ import annotations

from ..centroid import CentroidConfig
from ..parameter_spec import ParameterSpec, field_specs
from .autostart_parameter import AUTOSTART

RATE_SOURCES = ("topic", "imu", "parameter", "none")

# The node's own (no core field). exposure_time_s defaults to the shipped simulator's exposure
# (0.1 s), so `ros2 run star_tracker centroider` has the rate aid as with the params file.
NODE_PARAMETERS = [
    ParameterSpec("exposure_time_s", 0.1, "the camera's exposure, for the rate aid's smear prediction; 0 = unknown "
                  "(rate aid off)", "s", 0.0, 100.0, dynamic=True),
    ParameterSpec("rate_source", "topic", "body rate for the rate aid: topic (angular_velocity, Vector3Stamped), "
                  "imu (imu, sensor_msgs/Imu), parameter (angular_velocity_rad_s) or none", choices=RATE_SOURCES,
                  dynamic=True),
    ParameterSpec("angular_velocity_rad_s", (0.0, 0.0, 0.0), "body rate in the sensor frame x, y, z when rate_source "
                  "is parameter", "rad/s", dynamic=True),
    ParameterSpec("max_rate_age_s", 0.5, "ignore a rate message further than this from the image stamp", "s", 0.0,
                  1e6, dynamic=True),
    ParameterSpec("queue_depth", 3, "images waiting for the extraction at most; when one more arrives the oldest is "
                  "dropped and counted (frames_dropped_overload). 1 = only the newest frame waits; 3 rides out a "
                  "host stall of ~3 frames", "", 1, 100),
    ParameterSpec("stamp.max_future_s", 1.0, "count frames stamped further ahead of this node's clock "
                  "(frames_from_future); 0 = no check", "s", 0.0, 1e9, dynamic=True),
    ParameterSpec("stamp.reset_after_s", 2.0, "a frame older than the newest by more than this restarts time "
                  "(replay, simulation reset), counted as a time reset", "s", 0.0, 1e9, dynamic=True),
    ParameterSpec("gyro.mounting_quaternion", (0.0, 0.0, 0.0, 1.0), "orientation (x, y, z, w) of the gyro frame in "
                  "the sensor frame: v_sensor = R(q) v_gyro (imu, and angular_velocity in gyro.frame_id); unit norm"),
    ParameterSpec("gyro.noise_rad_s", 0.0, "the gyro's white noise per sample, 1 sigma per axis, for the covariance "
                  "of a frame carried along the gyro's path when its messages state none (angular_velocity; an imu "
                  "whose angular_velocity_covariance is all zeros); 0 = not known", "rad/s", 0.0, 1.0),
    ParameterSpec("gyro.frame_id", "", "frame_id of the gyro's messages; an imu message in another frame is "
                  "ignored, counted (rates_wrong_frame); '' = not checked"),
    AUTOSTART,
]

CENTROIDER_PARAMETERS = field_specs(CentroidConfig) + NODE_PARAMETERS
