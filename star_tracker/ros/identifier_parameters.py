# SPDX-License-Identifier: Apache-2.0
"""
The identifier's parameters, each declared once (ROS-free).

The fields of DatabaseConfig, IdentifyConfig, TrackingConfig and OnlineCalibrationConfig (their
spec is the dataclass field metadata) under the node's names, and the node's own, in the order
the node declares them and config/star_tracker.yaml lists them.

Dynamic (`ros2 param set` while running): the identification tolerances and time budget (read
by every identify() call: applied from the next solve), inline_wait_s, tracking.enabled, the
stamp checks; read-only: what is built at startup (database, algorithm, deep catalog, tracking).
"""
from __future__ import annotations

import time

from ..identify import ALGORITHMS, DEFAULT_ALGORITHM, DatabaseConfig, IdentifyConfig
from ..models.catalog import julian_year_from_unix
from ..models.sky_geometry import ExclusionModel
from ..models.online_calibration import OnlineCalibrationConfig
from ..parameter_spec import ParameterSpec, field_specs
from .autostart_parameter import AUTOSTART
from .observer_parameters import OBSERVER_PARAMETERS
from ..track.tracking import TrackingConfig

DATABASE_PARAMETERS = [
    *field_specs(DatabaseConfig, prefix="database.", only=("magnitude_limit",)),
    ParameterSpec("database.max_pair_angle_deg", DatabaseConfig.DEFAULT_PAIR_ANGLE_DEG, "largest stored star "
                  "separation; >= the camera's diagonal field of view", "deg", 0.1, 90.0),
    # The node's own (DatabaseConfig.epoch_jyear takes the year it resolves to, epoch_from_clock).
    ParameterSpec("database.epoch_jyear", 0.0, "epoch of the guide-star positions; 0 = the node clock's date at "
                  "startup, to 0.1 year (as the simulator's sky.epoch_jyear)", "Julian year", 0.0, 2200.0),
]

# Resolution of database.epoch_jyear = 0: one pattern database per tenth of a year (~0.8 s to
# build, cached), off the date by at most 0.05 year: a 1"/yr star by 0.05".
EPOCH_STEP_JYEAR = 0.1


def epoch_from_clock(epoch_jyear: float, clock_unix_s: float | None) -> float:
    """
    Return the guide-star epoch [Julian year] for database.epoch_jyear (0: the clock's date).

    clock_unix_s: the node's clock [s], None or 0 while a sim clock has not ticked (the wall
    clock is used). The date is rounded to EPOCH_STEP_JYEAR, so the cached databases are few.
    """
    if epoch_jyear:
        return float(epoch_jyear)
    year = julian_year_from_unix(clock_unix_s or time.time())
    return round(round(year / EPOCH_STEP_JYEAR) * EPOCH_STEP_JYEAR, 6)


IDENTIFY_PARAMETERS = field_specs(IdentifyConfig, names={"deep_match": "deep_match.enabled",
                                                         "deep_magnitude_margin": "deep_match.magnitude_margin"})

EXCLUSION_PARAMETERS = field_specs(ExclusionModel, prefix="exclusion.")
# In orbit (ros/in_orbit.py): the observer's velocity (aberration) and position (exclusion prediction),
# the head's per-frame status.
IN_ORBIT_PARAMETERS = [
    *OBSERVER_PARAMETERS,
    ParameterSpec("observer.correct_aberration", True, "publish the attitude corrected for the observer's velocity "
                  "(stellar aberration, up to ~25\"); false = fitted to the catalog's astrometric directions"),
    ParameterSpec("status.max_rate_deg_s", 6.0, "a head without an attitude whose last rate estimate exceeds this "
                  "reports rate_too_high", "deg/s", 0.0, 1e3),
    *EXCLUSION_PARAMETERS,
]

IDENTIFIER_PARAMETERS = [
    ParameterSpec("algorithm", DEFAULT_ALGORITHM, "identification algorithm", choices=tuple(sorted(ALGORITHMS))),
    ParameterSpec("frame_id", "icrs", "parent frame of the published attitude"),
    *DATABASE_PARAMETERS,
    *IDENTIFY_PARAMETERS,
    ParameterSpec("inline_wait_s", 0.05, "wait this long for a lost-in-space solve before bridging newer frames "
                  "(delay compensation)", "s", 0.0, 10.0, dynamic=True),
    ParameterSpec("calibration.enabled", False, "refine the focal length and k1 online from the identified stars "
                  "(thermo-elastic drift); applied to identification only when constrained "
                  "(calibration.apply_corner_sigma_px)"),
    *field_specs(OnlineCalibrationConfig, prefix="calibration."),
    ParameterSpec("queue_depth", 3, "spots frames waiting for identification at most; when one more arrives the "
                  "oldest is dropped and counted (frames_dropped_overload). 1 = only the newest frame waits; 3 rides "
                  "out a host stall of ~3 frames", "", 1, 100),
    ParameterSpec("stamp.max_future_s", 1.0, "drop frames stamped further ahead of this node's clock "
                  "(frames_from_future); 0 = no check", "s", 0.0, 1e9, dynamic=True),
    ParameterSpec("stamp.reset_after_s", 2.0, "a frame older than the newest by more than this restarts the track "
                  "(replay, simulation reset; time_resets); a less old one is dropped", "s", 0.0, 1e9, dynamic=True),
    ParameterSpec("tracking.enabled", True, "track from the previous attitude; false = lost-in-space on every frame",
                  dynamic=True),
    *field_specs(TrackingConfig, prefix="tracking."),
    *IN_ORBIT_PARAMETERS,
    AUTOSTART,
]

# Spec lists by the record they fill (field_values picks each record's fields by name).
TRACKING_PARAMETERS = [spec for spec in IDENTIFIER_PARAMETERS if spec.name.startswith("tracking.") and spec.field]
CALIBRATION_PARAMETERS = [spec for spec in IDENTIFIER_PARAMETERS if spec.name.startswith("calibration.")
                          and spec.field]
