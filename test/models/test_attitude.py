# SPDX-License-Identifier: Apache-2.0
"""
Attitude representations (models/attitude.py).

RA/Dec/roll and quaternion round trips, and the image orientation convention of roll = 0.
"""
import numpy as np
import pytest

from star_tracker.models.attitude import (matrix_to_quaternion, matrix_to_radec_roll, quaternion_to_matrix,
                                          radec_roll_to_matrix)
from star_tracker.models.camera import CameraModel


def test_radec_roll_round_trip_and_conventions():
    for ra, dec, roll in [(0.3, 0.5, 0.2), (5.0, -1.2, -2.9), (1.0, 1.5707, 0.0)]:
        rot = radec_roll_to_matrix(ra, dec, roll)
        assert np.allclose(rot.T @ rot, np.eye(3), atol=1e-12) and np.linalg.det(rot) == pytest.approx(1.0)
        ra2, dec2, roll2 = matrix_to_radec_roll(rot)
        assert np.allclose(radec_roll_to_matrix(ra2, dec2, roll2), rot, atol=1e-9)
        assert np.allclose(matrix_to_quaternion(quaternion_to_matrix(matrix_to_quaternion(rot))),
                           matrix_to_quaternion(rot))


def test_roll_zero_puts_north_up_and_east_left():
    # Looking out at the sky with north up, east is on the left: a star north of the boresight
    # lands above the centre (smaller row), one east of it left of the centre (smaller column).
    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0))
    ra, dec = 1.0, 0.3
    rot = radec_roll_to_matrix(ra, dec, 0.0)

    def pixel(ra_s, dec_s):
        v = np.array([np.cos(dec_s) * np.cos(ra_s), np.cos(dec_s) * np.sin(ra_s), np.sin(dec_s)])
        u, vv, _ = camera.project((v @ rot)[None])
        return u[0], vv[0]
    north = pixel(ra, dec + 0.02)
    east = pixel(ra + 0.02, dec)
    assert north[1] < camera.cy and abs(north[0] - camera.cx) < 1e-6
    assert east[0] < camera.cx
