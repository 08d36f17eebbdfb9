# SPDX-License-Identifier: Apache-2.0
"""
What the rendered-frame presets (accuracy, tracking, robustness) share in each worker process.

The default camera (1024 x 1024, 15 deg), the simulator's default SensorModel, Hipparcos at the
pattern database's epoch (rendered to MAGNITUDE_LIMIT) and the default identifier (`hybrid`,
its time budget on the CPU clock: scoring.campaign_identify_config). Each preset warms up what
it runs (the identifier, or a Tracker around it) and builds its renderers from these.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

MAGNITUDE_LIMIT = 7.5  # the rendered sky [Hp]


@dataclass
class DefaultChain:
    """camera: CameraModel; sensor: SensorModel; catalog: StarCatalog at the database epoch; identifier."""

    camera: object
    sensor: object
    catalog: object
    identifier: object


def default_chain() -> DefaultChain:
    """Return the default camera, sensor, catalog and lost-in-space identifier (not warmed up)."""
    from ...identify import DatabaseConfig, load_or_build_database, make_identifier
    from ...models.camera import CameraModel
    from ...models.catalog import load_hipparcos
    from ...sim.sensor import SensorModel
    from .scoring import campaign_identify_config

    database = load_or_build_database(DatabaseConfig())
    return DefaultChain(CameraModel.from_fov(1024, 1024, math.radians(15.0)), SensorModel(),
                        load_hipparcos().at_epoch(database.config.epoch_jyear),
                        make_identifier("hybrid", database, campaign_identify_config()))
