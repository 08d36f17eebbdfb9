# SPDX-License-Identifier: Apache-2.0
"""The campaign kinds `star-tracker characterize` knows, by preset name."""
from __future__ import annotations

from .false_id import FalseIdentification
from .sky_coverage import SkyCoverage

KINDS = {kind.name: kind for kind in (FalseIdentification, SkyCoverage)}

__all__ = ["KINDS", "FalseIdentification", "SkyCoverage"]
