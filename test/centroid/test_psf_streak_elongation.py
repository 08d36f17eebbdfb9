# SPDX-License-Identifier: Apache-2.0
"""
An unaided frame of long streaks of a wide PSF is estimated elongated and measured at its minor axis.

A 2.5 px PSF smeared 18 px has an axis ratio of ~2.5 (round enough for the estimate's star
test, MAX_AXIS_RATIO 3). The weighted moments (a weight twice the round fit's ~4.4 px) take in
enough sky beside the streaks that a sky ramp left them unmeasurable; the frame then read as a
round 4.4 px PSF: no spot was a streak and streaks were fitted as points off their centres.
The stars' adaptive moments give the elongation there. Stress campaign task 479 frame 13
(seed 2026, an accelerating slew, lost-in-space): 50" off, NEES 80, a wrong star; 0.5" now.
Independent renderer, a 1.2 e-/px/px sky ramp: 25-27 of 40 stars within 1 px, 9-11 stray
spots, no streak; now 37-38, streaks fitted.
"""
from __future__ import annotations

import numpy as np
import pytest

from bench import alt_renderer as alt
from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid.psf.estimate import SMEARED_ELONGATION
from star_tracker.centroid.spots import FLAG_STREAK

from smeared_alt_frames import found, smeared_frame
from stress_replay import prepared, replay_to


@pytest.mark.parametrize("seed", [1, 2])
def test_long_streaks_on_a_sky_ramp_are_not_a_wide_round_psf(seed):
    frame = smeared_frame(alt.GaussianPsf(2.5), 18.0, 0.3 + seed, seed, ramp_e_per_px=1.2, sky_e=500.0)
    spots = extract_spots(frame.image, CentroidConfig(), None, psf_prior=2.5)
    assert spots.psf.elongation > SMEARED_ELONGATION, spots.psf
    assert spots.psf.applied_sigma_px < 1.1 * 2.5, spots.psf
    assert np.count_nonzero(spots.flags & FLAG_STREAK) >= 25
    stars, _ = found(spots, frame.x, frame.y)
    assert stars >= 35, stars


@pytest.mark.slow
def test_stress_task_479_frame_13_unaided_slew_is_solved_on_its_streaks():
    row = replay_to(prepared(), 479, 13)[-1]
    assert row["frame"] == 13 and not row["aided"] and row["solved"], row
    assert not row["wrong"] and not row["wrong_star"] and row["matched"] >= 15, row
