# SPDX-License-Identifier: Apache-2.0
"""
The Spots record.

Building it from pixel positions (Spots.from_xy) and the checks that refuse malformed arrays
before they reach a compiled kernel.
"""
from __future__ import annotations

import numpy as np
import pytest

from star_tracker.centroid import FLUX_AT_MAGNITUDE_0, Spots


def valid_fields(n: int = 3) -> dict:
    return dict(x=np.arange(n) + 10.0, y=np.arange(n) + 20.0, flux=np.full(n, 1e4), snr=np.full(n, 50.0),
                cov=np.tile(np.eye(2) * 0.01, (n, 1, 1)), flags=np.zeros(n, np.uint32), area=np.full(n, 9, np.int32),
                peak=np.full(n, 1e3), width=1024, height=768)


def test_from_xy_places_the_spots_given():
    x, y = np.array([100.25, 511.5, 3.0]), np.array([7.75, 300.0, 767.0])
    magnitude = np.array([1.0, 2.5, 6.0])
    spots = Spots.from_xy(x, y, magnitude, sigma_px=0.3, width=1024, height=768)
    assert len(spots) == 3 and (spots.width, spots.height) == (1024, 768)
    assert np.array_equal(spots.x, x) and np.array_equal(spots.y, y)  # same order, same values
    # 5 magnitudes = a factor 100 in flux; magnitude 0 is the zero point.
    np.testing.assert_allclose(spots.flux, FLUX_AT_MAGNITUDE_0 * np.array([10 ** -0.4, 10 ** -1.0, 10 ** -2.4]),
                               rtol=1e-12)
    np.testing.assert_allclose(spots.flux[0] / spots.flux[2], 100.0, rtol=1e-12)
    assert np.array_equal(spots.cov, np.tile(np.diag([0.09, 0.09]), (3, 1, 1)))
    assert not spots.flags.any() and np.array_equal(spots.streak_length, np.zeros(3))
    assert spots.flags.dtype == np.uint32 and spots.area.dtype == np.int32


def test_from_xy_without_magnitudes_and_with_a_zero_point():
    spots = Spots.from_xy([1.0, 2.0], [3.0, 4.0], sigma_px=1.0, width=10, height=10)
    assert np.array_equal(spots.flux, np.full(2, FLUX_AT_MAGNITUDE_0))
    scaled = Spots.from_xy([1.0], [3.0], [5.0], sigma_px=1.0, width=10, height=10, flux_at_magnitude_0=2.0e4)
    np.testing.assert_allclose(scaled.flux, [200.0], rtol=1e-12)


def test_take_and_empty_build_valid_records():
    spots = Spots(**valid_fields(4))
    assert np.array_equal(spots.take(np.array([3, 1])).x, [13.0, 11.0])
    assert len(spots.take(np.zeros(4, bool))) == 0
    assert len(Spots.empty(64, 64)) == 0


@pytest.mark.parametrize("field", ["y", "flux", "snr", "flags", "area", "peak", "streak_length", "streak_angle"])
def test_a_per_spot_array_one_short_is_refused(field):
    fields = valid_fields(3)
    short = np.zeros(2, fields[field].dtype if field in fields else float)
    fields[field] = short
    with pytest.raises(ValueError, match=rf"Spots\.{field} must have shape \(3,\) like x, got \(2,\)"):
        Spots(**fields)


def test_a_covariance_without_its_2x2_blocks_is_refused():
    fields = valid_fields(3)
    fields["cov"] = np.full((3, 2), 0.01)
    with pytest.raises(ValueError, match=r"Spots\.cov must have shape \(3, 2, 2\), got \(3, 2\)"):
        Spots(**fields)


def test_x_must_be_one_dimensional():
    fields = valid_fields(3)
    fields["x"] = fields["x"][:, None]
    with pytest.raises(ValueError, match=r"Spots\.x must have shape \(N,\), got \(3, 1\)"):
        Spots(**fields)


@pytest.mark.parametrize("field, value, message", [
    ("flux", np.ones(3, np.int64), r"Spots\.flux must have a float dtype, got int64"),
    ("cov", np.tile(np.eye(2, dtype=np.int64), (3, 1, 1)), r"Spots\.cov must have a float dtype, got int64"),
    ("flags", np.zeros(3), r"Spots\.flags must have an integer dtype, got float64"),
    ("area", np.ones(3, bool), r"Spots\.area must have an integer dtype, got bool"),
    ("x", [10.0, 11.0, 12.0], r"Spots\.x must be a numpy array, got list"),
    ("width", 0, r"Spots\.width must be a positive integer \[px\], got 0"),
    ("height", 768.0, r"Spots\.height must be a positive integer \[px\], got 768\.0"),
])
def test_wrong_types_are_refused_by_name(field, value, message):
    fields = valid_fields(3)
    fields[field] = value
    with pytest.raises(ValueError, match=message):
        Spots(**fields)


def test_non_finite_values_pass():
    """Values are the consumer's to judge (ros.convert.drop_invalid_spots): only structure is checked."""
    fields = valid_fields(2)
    fields["x"] = np.array([np.nan, np.inf])
    fields["cov"] = np.full((2, 2, 2), np.inf)
    assert len(Spots(**fields)) == 2
