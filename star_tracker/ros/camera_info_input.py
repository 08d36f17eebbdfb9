# SPDX-License-Identifier: Apache-2.0
"""
The camera model a node reads from `camera_info`.

Parsed when the message changes, an invalid one counted, logged and ignored (the last good
model is kept).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node

from . import convert

if TYPE_CHECKING:  # annotations only
    from .diagnostics import Diagnostics
    from .throttled_log import ThrottledLog


class CameraInfoInput:
    """
    The camera model from `camera_info` messages.

    Parsed only when the message changes; an invalid one (or one `check` refuses with a
    reason) is counted as camera_info_rejected on /diagnostics, logged, and ignored, keeping
    the last good model in `camera`.
    """

    def __init__(self, node: Node, diag: "Diagnostics", log: "ThrottledLog",
                 check: Callable[[object], str | None] | None = None):
        self.node, self.diag, self.log, self.check = node, diag, log, check
        self.camera = None
        self._key = None

    def update(self, msg) -> None:
        key = (msg.width, msg.height, tuple(msg.k), tuple(msg.d), msg.distortion_model)
        if key == self._key:
            return
        try:
            camera = convert.info_to_camera(msg)
            reason = self.check(camera) if self.check else None
        except ValueError as exc:
            reason = str(exc)
        if reason:
            self.diag.count("camera_info_rejected")
            self.diag.set(DiagnosticStatus.WARN, f"rejected camera_info: {reason}")
            self.log.warn("bad_info", f"rejected camera_info: {reason}")
            return
        self.camera, self._key = camera, key
        self.node.get_logger().info(f"camera model: {camera.width}x{camera.height} px, fx={camera.fx:.2f} px")
