# SPDX-License-Identifier: Apache-2.0
"""The one parameter every managed node shares (ROS-free spec, see managed_node.py)."""
from __future__ import annotations

from ..parameter_spec import ParameterSpec

AUTOSTART = ParameterSpec("autostart", True, "configure and activate on start (one-command `ros2 run`); false = "
                          "stay unconfigured until `ros2 lifecycle set <node> configure`")
