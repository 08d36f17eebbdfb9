# SPDX-License-Identifier: Apache-2.0
"""The campaign kinds `star-tracker characterize` knows, by preset name."""
from __future__ import annotations

from .accuracy import Accuracy
from .false_id import FalseIdentification
from .robustness import Robustness
from .sky_coverage import SkyCoverage
from .stress import Stress
from .tracking import Tracking

KINDS = {kind.name: kind for kind in (FalseIdentification, SkyCoverage, Accuracy, Tracking, Robustness, Stress)}

__all__ = ["KINDS", "Accuracy", "FalseIdentification", "Robustness", "SkyCoverage", "Stress", "Tracking"]
