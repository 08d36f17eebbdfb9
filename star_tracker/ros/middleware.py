# SPDX-License-Identifier: Apache-2.0
"""
DDS middleware configuration.

star_tracker's Fast DDS profile (a shared-memory segment large enough for 2 MiB frames),
unless the user chose a profile; and the shared-memory files ended processes left removed
(shared_memory.py).
"""
from __future__ import annotations

import os
from pathlib import Path

from .shared_memory import remove_stale_shared_memory

FASTDDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")
_PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def configure_middleware(environ=os.environ) -> None:
    """
    Use star_tracker's Fast DDS profile (large shared-memory segment for 2 MiB frames) unless the user chose a profile.

    Must run before rclpy.init() in every process. Also removes what ended processes left in
    /dev/shm (shared_memory.remove_stale_shared_memory).
    """
    if not any(environ.get(name) for name in _PROFILE_VARIABLES):
        environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(FASTDDS_PROFILE)
    remove_stale_shared_memory(environ=environ)
