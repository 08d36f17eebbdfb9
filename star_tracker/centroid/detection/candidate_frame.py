# SPDX-License-Identifier: Apache-2.0
"""CandidateFrame: one frame as the measurement of its candidates (and the search for tracks in them) reads it."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..config import CentroidConfig
from .detect import Detections


class CandidateFrame(NamedTuple):
    """
    One frame as the measurement of its candidates reads it.

    image [ADU]; det: its detections; config: the stage's CentroidConfig; sigma: the PSF
    1-sigma measured with [px]; find_blends: search elongated footprints for two stars; rings:
    the stars are rings (blend peaks farther apart, config.blend_separation_px);
    streaks_expected: a body rate predicts streaks (the footprints are the matched streak
    filter's, taken as they are).
    """

    image: np.ndarray
    det: Detections
    config: CentroidConfig
    sigma: float
    find_blends: bool
    rings: bool
    streaks_expected: bool
