# SPDX-License-Identifier: Apache-2.0
"""
Replays of `star-tracker characterize stress` missions (seed 2026) up to a frame, scored on the simulator's truth.

The mission draws from np.random.SeedSequence([2026, task]); its schedule is cut after the
frame in question and run by stress.run_mission: the tracker and the running PSF carried from
frame to frame as in the campaign. Each row: solved, wrong, wrong_star, cross_arcsec, nees.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from star_tracker.campaign.presets import stress

SEED = 2026


def prepared():
    """Return the campaign's options and shared state (catalog, database, identifier)."""
    options = stress.StressOptions()
    return options, stress.Stress().prepare(options)


def replay_to(campaign, task: int, frame: int) -> list[dict]:
    """Return the frames of mission `task` delivered up to and including `frame`."""
    options, shared = campaign
    rng = np.random.default_rng(np.random.SeedSequence([SEED, task]))
    mission = stress.draw_mission(rng, options.frames_per_mission, shared.sensor)
    last = max(k for k, entry in enumerate(mission.schedule) if entry[0] == frame)
    mission = replace(mission, schedule=mission.schedule[:last + 1],
                      events=[event for event in mission.events if event <= last])
    _, frames = stress.run_mission(shared, options, rng, mission)
    return frames
