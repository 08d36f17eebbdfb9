# SPDX-License-Identifier: Apache-2.0
"""
The records the centroiding steps pass each other (centroid.records).

A fit step writes its values into a copy of the spot table and returns the stars it split off
as rows of their own.
"""
from __future__ import annotations

import numpy as np

from star_tracker.centroid import FLAG_BLENDED, FLAG_STREAK
from star_tracker.centroid.records import FittedStars, SpotRows, no_spots


def table(n: int = 4) -> SpotRows:
    return SpotRows(x=np.arange(n) * 10.0, y=np.arange(n) * 5.0, flux=np.full(n, 1e4), snr=np.full(n, 20.0),
                    cov=np.tile(np.eye(2) * 0.04, (n, 1, 1)), flags=np.zeros(n, np.uint32), length=np.zeros(n),
                    angle=np.zeros(n), peak=np.full(n, 900.0), area=np.full(n, 12, np.int64))


def test_with_values_writes_a_copy_and_leaves_the_table_alone():
    spots = table()
    index = np.array([1, 3])
    fitted = spots.with_values(index, x=np.array([10.25, 30.5]), flags=spots.flags[index] | FLAG_BLENDED)
    assert np.array_equal(fitted.x, [0.0, 10.25, 20.0, 30.5])
    assert np.array_equal(fitted.flags, [0, FLAG_BLENDED, 0, FLAG_BLENDED]) and fitted.flags.dtype == np.uint32
    assert np.array_equal(spots.x, [0.0, 10.0, 20.0, 30.0]) and not spots.flags.any()  # untouched
    assert fitted.y is spots.y  # fields not written are shared, not copied


def test_with_stars_writes_a_fits_position_flux_covariance_and_snr():
    spots = table()
    stars = FittedStars(np.array([1.5]), np.array([2.5]), np.array([3.0e4]), np.full((1, 2, 2), 0.01),
                        np.array([80.0]))
    fitted = spots.with_stars(np.array([2]), stars)
    assert (fitted.x[2], fitted.y[2], fitted.flux[2], fitted.snr[2]) == (1.5, 2.5, 3.0e4, 80.0)
    assert np.array_equal(fitted.cov[2], np.full((2, 2), 0.01)) and np.array_equal(fitted.cov[0], np.eye(2) * 0.04)


def test_split_off_stars_are_rows_without_a_detection_of_their_own():
    stars = FittedStars(np.array([4.0, 6.0]), np.array([7.0, 9.0]), np.array([500.0, 400.0]),
                        np.tile(np.eye(2), (2, 1, 1)), np.array([9.0, 7.0]))
    points = SpotRows.split_off(stars, peak=np.array([50.0, 40.0]), flags=FLAG_BLENDED)
    assert np.array_equal(points.area, [0, 0]) and np.array_equal(points.flags, [FLAG_BLENDED] * 2)
    assert np.array_equal(points.length, [0.0, 0.0]) and np.array_equal(points.peak, [50.0, 40.0])
    streaks = SpotRows.split_off(stars, np.array([50.0, 40.0]), FLAG_STREAK | FLAG_BLENDED, np.array([12.0, 13.0]),
                                 np.array([0.5, -0.5]))
    assert np.array_equal(streaks.length, [12.0, 13.0]) and np.array_equal(streaks.angle, [0.5, -0.5])
    both = SpotRows.concatenate([table(2), points, no_spots(), streaks])
    assert len(both) == 6 and np.array_equal(both.x, [0.0, 10.0, 4.0, 6.0, 4.0, 6.0])
    assert both.flags.dtype == np.uint32 and both.area.dtype == np.int64 and both.cov.shape == (6, 2, 2)
    assert np.array_equal(both.area, [12, 12, 0, 0, 0, 0])


def test_fitted_stars_take_and_concatenate_keep_the_order():
    stars = FittedStars(np.arange(3.0), np.arange(3.0) + 10, np.full(3, 1e3), np.zeros((3, 2, 2)), np.arange(3.0))
    picked = FittedStars.concatenate([stars.take(np.array([2])), stars.take(slice(0, 1))])
    assert np.array_equal(picked.x, [2.0, 0.0]) and np.array_equal(picked.y, [12.0, 10.0])
    assert picked.cov.shape == (2, 2, 2)
