# SPDX-License-Identifier: Apache-2.0
"""
Star identification.

Every algorithm implements `StarIdentifier.identify(spots, camera)` and is chosen by name
with `make_identifier`. Shared machinery: database, k-vector, verification, and the final
QUEST refinement in `base`.
"""
from __future__ import annotations

from .base import Identification, IdentifyConfig, StarIdentifier
from .database import DatabaseConfig, StarDatabase, load_or_build_database
from .angle_pivot import AnglePivotIdentifier
from .composite import CompositeIdentifier
from .hybrid import HybridIdentifier
from .match_groups import MatchGroupIdentifier
from .pyramid import PyramidIdentifier
from .spherical_triangle import SphericalTriangleIdentifier

ALGORITHMS: dict[str, type[StarIdentifier]] = {
    PyramidIdentifier.name: PyramidIdentifier,
    HybridIdentifier.name: HybridIdentifier,
    AnglePivotIdentifier.name: AnglePivotIdentifier,
    MatchGroupIdentifier.name: MatchGroupIdentifier,
    SphericalTriangleIdentifier.name: SphericalTriangleIdentifier,
    CompositeIdentifier.name: CompositeIdentifier,
}
DEFAULT_ALGORITHM = HybridIdentifier.name


def make_identifier(name: str, database: StarDatabase, config: IdentifyConfig | None = None) -> StarIdentifier:
    """Instantiate the identification algorithm `name` (one of ALGORITHMS)."""
    try:
        cls = ALGORITHMS[name]
    except KeyError:
        raise ValueError(f"unknown identification algorithm {name!r}; choose from {sorted(ALGORITHMS)}") from None
    return cls(database, config or IdentifyConfig())


__all__ = ["ALGORITHMS", "DEFAULT_ALGORITHM", "DatabaseConfig", "Identification", "IdentifyConfig",
           "StarDatabase", "StarIdentifier", "load_or_build_database", "make_identifier"]
