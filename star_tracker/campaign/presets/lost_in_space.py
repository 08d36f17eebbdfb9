# SPDX-License-Identifier: Apache-2.0
"""
What the lost-in-space presets share: their scene options and what a worker prepares once.

A scene is made as the identification benchmark makes them (sim/scenes.py: a setup of
SETUPS, `false_stars` false objects added) and identified by `algorithm` with the campaign's
identifier configuration (scoring.campaign_identify_config); `wrong_arcsec` is the scoring's.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ...parameter_spec import parameter, range_problems
from .scoring import campaign_identify_config


@dataclass(frozen=True)
class SceneOptions:
    """The scenes and the identifier of a lost-in-space campaign (each a `parameter`); a preset adds its own."""

    setup: str = parameter("nominal", "scene setup of sim/scenes.SETUPS (camera, magnitude limit, noise)")
    false_stars: int = parameter(2, "false objects added to every scene (uniform over the field)", "", 0, 1000)
    algorithm: str = parameter("hybrid", "identification algorithm (identify.ALGORITHMS)")
    wrong_arcsec: float = parameter(60.0, "a boresight this far from the truth is wrong", "arcsec", 0.0, 1e6,
                                    low_open=True)

    def problems(self) -> list[str]:
        """Return what is out of range or unknown among the options (empty when all is well)."""
        from ...identify import ALGORITHMS
        from ...sim.scenes import SETUPS

        bad = range_problems(self)
        if self.setup not in SETUPS:
            bad.append(f"setup={self.setup!r}: expected one of {sorted(SETUPS)}")
        if self.algorithm not in ALGORITHMS:
            bad.append(f"algorithm={self.algorithm!r}: expected one of {sorted(ALGORITHMS)}")
        return bad


@dataclass
class SceneShared:
    """Per worker process: the setup, the catalog cut to its limit, its unit vectors, the identifier."""

    setup: object
    catalog: object
    vectors: np.ndarray
    identifier: object


def prepare_scenes(options: SceneOptions, magnitude_limit: float | None = None) -> SceneShared:
    """
    Build what every trial of a worker shares (the stars and their directions once: make_scene would each call).

    magnitude_limit [Hp mag]: the faintest star making a spot, replacing the setup's (None: the setup's).
    """
    from ...identify import DatabaseConfig, load_or_build_database, make_identifier
    from ...models.catalog import load_hipparcos
    from ...sim.scenes import SETUPS

    setup = dataclasses.replace(SETUPS[options.setup], false_stars=options.false_stars)
    if magnitude_limit is not None:
        setup = dataclasses.replace(setup, magnitude_limit=float(magnitude_limit))
    database = load_or_build_database(DatabaseConfig())
    catalog = load_hipparcos().at_epoch(database.config.epoch_jyear).brighter_than(setup.magnitude_limit)
    identifier = make_identifier(options.algorithm, database, campaign_identify_config())
    return SceneShared(setup, catalog, catalog.unit_vectors(), identifier)
