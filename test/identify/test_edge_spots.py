# SPDX-License-Identifier: Apache-2.0
"""Spots whose light runs past the image border (flag EDGE) are published but not named."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from conftest import spots_at

from star_tracker.centroid import FLAG_EDGE, FLAG_STREAK
from star_tracker.centroid.frame_fits import runs_past_border
from star_tracker.centroid.records import SpotRows
from star_tracker.identify import IdentifyConfig, make_identifier
from star_tracker.models.attitude import attitude_error, radec_roll_to_matrix


def test_edge_spots_are_left_out_and_the_rest_solve(catalog, nominal_camera, database):
    truth = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.0)
    spots = spots_at(catalog, nominal_camera, truth)
    identifier = make_identifier("hybrid", database, IdentifyConfig())
    named = identifier.identify(spots, nominal_camera)
    assert named.solved and {0, 1, 2} <= set(named.spot_index.tolist())  # the three brightest are named
    flags = spots.flags.copy()
    flags[[0, 1, 2]] |= FLAG_EDGE
    result = identifier.identify(replace(spots, flags=flags), nominal_camera)
    assert result.solved and not {0, 1, 2} & set(result.spot_index.tolist())
    assert result.spot_index.size == named.spot_index.size - 3
    assert np.degrees(attitude_error(result.attitude.rotation, truth)[0]) * 3600 < 1.0  # cross-boresight


def test_a_streak_is_flagged_edge_when_its_segment_runs_past_the_border():
    # 1024 x 1024: a 19.4 px streak along 161 deg centred 0.3 px inside the right border (stress
    # task 2217 frame 31), the same 20 px inside, a point at the border, a streak along the border.
    x = np.array([1021.2, 1001.2, 1023.0, 500.0])
    y = np.array([243.5, 243.5, 500.0, 1022.0])
    length = np.array([19.4, 19.4, 0.0, 30.0])
    angle = np.array([np.radians(161.0), np.radians(161.0), 0.0, 0.0])
    flags = np.array([FLAG_STREAK, FLAG_STREAK, 0, FLAG_STREAK], np.uint32)
    n = x.size
    rows = SpotRows(x, y, np.ones(n), np.ones(n), np.tile(np.eye(2), (n, 1, 1)), flags, length, angle, np.ones(n),
                    np.ones(n))
    assert runs_past_border(rows, 1024, 1024).tolist() == [True, False, False, False]
