# SPDX-License-Identifier: Apache-2.0
"""
The PSF width of a frame smeared by an unknown rate, measured across its streaks' own tracks.

Without a rate no star shows the round PSF, and no smear model gives the tracks' direction:
each bright spot's own second moments do (their major axis; the segment length at the prior,
smear.segment_length). The body's motion smears every star alike, so only the spots within
ANGLE_RAD of their median axis are measured (cosmic-ray tracks lie every way), and only when
most bright spots are streaks and most of those lie so (a frame at rest beside cosmic-ray
tracks is not smeared: under 2000 rays /cm^2/s, 7 tracks read as a 0.37 px PSF of 1 px stars;
nor is a frame of faint defocused rings, arcs at the 1 px prior), MIN_ALIGNED of them at least. A short undersampled
streak's moment axis is a few degrees off its track, and a profile across a track at an angle
reads wide (a 0.44 px PSF read 0.83 px: stress campaign, seed 2026, task 2344 frame 1): each is
measured along its axis turned by TURNS_RAD, the narrowest profile kept
(streak_width.streak_widths_along).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .smear import segment_length
from .streak_width import MIN_LENGTH_PX, MIN_SNR, MIN_STREAKS, frame_width, streak_widths_along

if TYPE_CHECKING:
    from ..detection.candidates import Candidates

ANGLE_RAD = math.radians(10.0)  # measured: the spots within this of their median axis
TURNS_RAD = tuple(math.radians(a) for a in (-6.0, -4.0, -2.0, 0.0, 2.0, 4.0, 6.0))
# Aligned streaks needed: three cosmic-ray tracks of the independent renderer lay within 6 deg
# of one another beside the faint rings of a 3 px annulus PSF, and read as a 0.47 px PSF.
MIN_ALIGNED = 5


def own_track_width(image: np.ndarray, cand: "Candidates", usable: np.ndarray, prior_sigma: float
                    ) -> tuple[float, float, int]:
    """
    Return (sigma [px], its 1-sigma uncertainty, streaks used) across the streaks' own tracks, or (nan, nan, n).

    image [ADU]; cand: the frame's candidates measured at `prior_sigma` [px]; usable (N,) bool:
    the candidates whose profile may be read (not clipped). NaN as well when fewer than half the
    bright candidates (SNR >= streak_width.MIN_SNR) are streaks, fewer than half of those (or
    than MIN_ALIGNED) lie within ANGLE_RAD of their median axis, or fewer than
    streak_width.MIN_STREAKS give a width.
    """
    length = segment_length(cand.major, prior_sigma)
    bright = usable & np.isfinite(cand.x) & np.isfinite(cand.y) & (cand.snr >= MIN_SNR)
    track = bright & np.isfinite(cand.angle) & (length >= MIN_LENGTH_PX)
    if np.count_nonzero(track) < max(MIN_STREAKS, 0.5 * np.count_nonzero(bright) + 0.5):
        return float("nan"), float("nan"), 0
    # Axes are directions mod pi: their median from the doubled angles.
    doubled = 2.0 * cand.angle[track]
    median = 0.5 * math.atan2(float(np.median(np.sin(doubled))), float(np.median(np.cos(doubled))))
    off = np.abs((cand.angle - median + 0.5 * np.pi) % np.pi - 0.5 * np.pi)
    aligned = track & (off <= ANGLE_RAD)
    if np.count_nonzero(aligned) < max(MIN_ALIGNED, 0.5 * np.count_nonzero(track)):
        return float("nan"), float("nan"), 0  # not one motion's streaks: arcs of rings, tracks
    track = aligned
    vectors = length[:, None] * np.column_stack([np.cos(cand.angle), np.sin(cand.angle)])
    widths = streak_widths_along(image, np.where(track, cand.x, np.nan), cand.y, cand.snr, vectors, TURNS_RAD)
    return frame_width(widths)
