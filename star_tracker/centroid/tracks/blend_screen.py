# SPDX-License-Identifier: Apache-2.0
"""
The width test per peak applied to a frame's blends: which blends hold a star, and which of their peaks are tracks.

The shape test judges a footprint as a whole; a star merged with a cosmic-ray track fails it
with the track. Here every blend the test kept, or rejected only for its width, is judged
peak by peak (peak_shape.peak_minor_moments).
"""
from __future__ import annotations

import numpy as np

from ..detection.candidates import Candidates
from ..records import FitContext
from .peak_shape import KEPT_BLEND_TRACK_FRACTION, RING_BLEND_TRACK_FRACTION, peak_minor_moments, peak_width_limit


def blends_beside_tracks(context: FitContext, cand: Candidates, rejected: np.ndarray, thin: np.ndarray,
                         narrowest: float) -> tuple[np.ndarray, dict]:
    """
    Apply the width test per peak to every blend kept or rejected only by it.

    A peak is a star when its second moment is >= min_width_fraction x TRUNCATED_MOMENT x
    narrowest^2 [px^2] (the limit) at an SNR >= shape_min_snr. A blend the width test rejected
    whole is kept when a peak is a star (its other peaks count as tracks); in a kept blend a
    peak below KEPT_BLEND_TRACK_FRACTION (ring stars: RING_BLEND_TRACK_FRACTION) x the limit at
    that SNR is a track (a cosmic ray merged with a star, which the footprint's moments did not
    show). Returns the rejections and, per
    blend with tracks, the mask of its track peaks and the peaks' PeakShapes.
    """
    config = context.config
    rejected, tracks = rejected.copy(), {}
    limit = peak_width_limit(config.min_width_fraction, narrowest)
    track_fraction = RING_BLEND_TRACK_FRACTION if context.rings else KEPT_BLEND_TRACK_FRACTION
    # A peak's SNR is at most its footprint's: fainter footprints have no measured peak.
    for i in np.flatnonzero((thin | ~rejected) & (cand.snr >= config.shape_min_snr)):
        peaks = cand.peaks[i]
        if len(peaks) < 2:
            continue
        shapes = peak_minor_moments(context.image, context.det, peaks, context.sigma, context.gain, centres=False)
        minor = shapes.minor
        measured = shapes.snr >= config.shape_min_snr
        star = measured & (minor >= limit)
        if not star.any():
            continue
        # In a blend the footprint test kept, only a peak far thinner than a star is a track: a
        # star's core without its wings (cut at 2.5 sigma) can read ~0.8x the limit on a real lens.
        track = ~star if rejected[i] else measured & (minor < track_fraction * limit)
        rejected[i] = False
        if track.any():  # their centres only where a fit may need the fallback
            tracks[int(i)] = (track, peak_minor_moments(context.image, context.det, peaks, context.sigma, context.gain))
    return rejected, tracks
