# SPDX-License-Identifier: Apache-2.0
"""
RunningPsf: the PSF width carried from frame to frame (the centroider node's prior).

With it the next frame usually needs one measurement pass (extract_spots(..., psf_prior=...,
prior_rings=...)): a defocused camera's ring stars too.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from .estimate import PsfEstimate


class RunningPsf:
    """
    The median [px] of the last `frames` frames' applied PSF widths.

    A frame whose estimate failed on what it measured (source not "estimated": a width out of
    range) empties it, so the next frame starts again from the configured prior instead of a
    stale width; one that had too little to measure its PSF on (PsfEstimate.holds_prior: no
    detections, too few isolated point-like stars, no PSF fit converged, too few streaks to
    measure across, too few of the usable stars round) leaves it as it is.
    """

    def __init__(self, frames: int = 5) -> None:
        if frames < 1:
            raise ValueError(f"frames={frames} must be >= 1")
        self._recent: deque[float] = deque(maxlen=frames)
        self._rings: deque[bool] = deque(maxlen=frames)

    def update(self, estimate: PsfEstimate | None) -> None:
        if estimate is not None and estimate.holds_prior:
            return  # no evidence against the widths held
        if estimate is None or not estimate.estimated:
            self.reset()
        else:
            # The width the frame was measured with, not the raw estimate: for smeared stars the
            # round estimate is wider than the PSF (extract_spots measured them with the minor axis).
            self._recent.append(float(estimate.applied_sigma_px))
            self._rings.append(bool(estimate.annular))

    def reset(self) -> None:
        self._recent.clear()
        self._rings.clear()

    @property
    def prior(self) -> float | None:
        """The width to start the next frame from [px], None: the configured prior."""
        return float(np.median(self._recent)) if self._recent else None

    @property
    def rings(self) -> bool:
        """Whether most of the last frames' stars were ring-shaped, a defocused PSF: extract_spots' prior_rings."""
        return 2 * sum(self._rings) > len(self._rings)
