# SPDX-License-Identifier: Apache-2.0
"""
The camera simulator's core.

Attitude motion, the sensor model, the frame renderer and synthetic centroid-list scenes
with truth. No ROS; the node is ros/camera_simulator_node.py.
"""
