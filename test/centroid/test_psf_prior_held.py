# SPDX-License-Identifier: Apache-2.0
"""
A frame with nothing to measure its PSF on keeps the running prior (PsfEstimate.holds_prior, RunningPsf).

Stress campaign (seed 2026): a rate-aided frame with too few bright streaks to measure across,
or whose usable stars were mostly elongated (tracks, smear), fell back to the prior and emptied
the running prior, so the next such frame started from the configured 1 px: task 99 frame 7
(a 2.8 px PSF after a too-few-streaks frame: 8 stars named, 57" off, NEES 524, a wrong star),
task 479 frame 26 (2.5 px, 19 px streaks: 61" off), task 585 frame 37 (3 px after a frame of
5 round and 6 elongated usable stars: NEES 33).
"""
from __future__ import annotations

from dataclasses import replace

import pytest

from star_tracker.centroid.psf.estimate import PsfEstimate
from star_tracker.centroid.psf.running_prior import RunningPsf

from stress_replay import prepared, replay_to


def test_running_prior_holds_through_a_frame_with_nothing_to_measure_and_empties_on_a_failed_estimate():
    psf = RunningPsf()
    psf.update(PsfEstimate(2.8, 2.8, 2.8, 0.0, 0.01, 10, "estimated"))
    held = PsfEstimate.assumed(2.8, "prior", "rate-aided frame: too few streaks to measure across")
    psf.update(replace(held, holds_prior=True))
    assert psf.prior == pytest.approx(2.8)
    psf.update(PsfEstimate.assumed(2.8, "prior", "3 isolated unsaturated point-like stars (need 5)"))
    assert psf.prior is None


@pytest.fixture(scope="module")
def campaign():
    return prepared()


@pytest.mark.slow
@pytest.mark.parametrize("task, frame", [(99, 7), (479, 26), (585, 37)])
def test_stress_frame_after_a_psf_fallback_starts_from_the_running_prior(campaign, task, frame):
    row = replay_to(campaign, task, frame)[-1]
    assert row["frame"] == frame and row["solved"], row
    assert not row["wrong"] and not row["wrong_star"] and row["matched"] >= 15, row
