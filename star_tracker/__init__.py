# SPDX-License-Identifier: Apache-2.0
"""
star_tracker: a simulated spacecraft star tracker.

The core (catalog, camera, motion, render, centroid, identify, attitude) is pure
numpy/OpenCV and never imports rclpy; `star_tracker.ros` holds the thin node adapters.
"""

__version__ = "0.1.0"
