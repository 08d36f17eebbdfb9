# SPDX-License-Identifier: Apache-2.0
"""The observer parameters: where the spacecraft's velocity and position come from (identifier, fusion; ROS-free)."""
from __future__ import annotations

from ..parameter_spec import ParameterSpec

OBSERVER_SOURCES = ("none", "fixed", "odometry")
OBSERVER_PARAMETERS = [
    ParameterSpec("observer.source", "none", "where the spacecraft's velocity (and position) come from: none = no "
                  "aberration correction or exclusion prediction; fixed = observer.velocity_m_s; odometry = the "
                  "odometry topic (GCRS) with the shipped ephemeris", choices=OBSERVER_SOURCES),
    ParameterSpec("observer.velocity_m_s", (0.0, 0.0, 0.0), "the observer's barycentric velocity on ICRS axes "
                  "(observer.source fixed)", "m/s"),
    ParameterSpec("observer.max_age_s", 60.0, "odometry older than this at a frame's stamp is not used (younger "
                  "is extrapolated along the orbit)", "s",
                  0.001, 1e6),
]
