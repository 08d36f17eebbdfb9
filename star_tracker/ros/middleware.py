# SPDX-License-Identifier: Apache-2.0
"""
DDS middleware configuration.

star_tracker's Fast DDS profile (a shared-memory segment large enough for 2 MiB frames),
unless the user chose a profile.
"""
from __future__ import annotations

import os
from pathlib import Path

FASTDDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")
_PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def configure_middleware(environ=os.environ) -> None:
    """
    Use star_tracker's Fast DDS profile (large shared-memory segment for 2 MiB frames) unless the user chose a profile.

    Must run before rclpy.init() in every process.
    """
    if not any(environ.get(name) for name in _PROFILE_VARIABLES):
        environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(FASTDDS_PROFILE)
