# SPDX-License-Identifier: Apache-2.0
"""database.epoch_jyear = 0: the identifier's guide stars at the clock's date (ROS-free)."""
from __future__ import annotations

import calendar
import time

import pytest

from star_tracker.models.catalog import julian_year_from_unix, load_hipparcos
from star_tracker.ros.identifier_parameters import EPOCH_STEP_JYEAR, epoch_from_clock


def unix(year: int, month: int, day: int) -> float:
    return float(calendar.timegm((year, month, day, 0, 0, 0)))


def test_a_set_epoch_is_kept():
    assert epoch_from_clock(2031.25, unix(2026, 12, 6)) == 2031.25


@pytest.mark.parametrize("date, epoch", [((2026, 12, 6), 2026.9), ((2026, 1, 1), 2026.0), ((2030, 7, 2), 2030.5)])
def test_zero_is_the_clocks_date_to_a_tenth_of_a_year(date, epoch):
    assert epoch_from_clock(0.0, unix(*date)) == pytest.approx(epoch, abs=1e-9)


def test_a_clock_that_has_not_ticked_is_the_wall_clock():
    for clock in (None, 0.0):
        resolved = epoch_from_clock(0.0, clock)
        assert abs(resolved - julian_year_from_unix(time.time())) <= EPOCH_STEP_JYEAR / 2 + 1e-6


def test_the_resolved_epoch_places_a_fast_star_where_the_simulator_renders_it():
    """61 Cyg A (HIP 104214, ~5.3"/yr): at the clock's date within 0.05 yr of motion; at a fixed 2026.0 not."""
    catalog = load_hipparcos()
    star = catalog.subset(catalog.hip == 104214)
    now = unix(2030, 7, 2)
    rendered = star.at_epoch(julian_year_from_unix(now)).unit_vectors()[0]  # the simulator's sky.epoch_jyear = 0
    arcsec = 4.84813681109536e-06
    resolved = star.at_epoch(epoch_from_clock(0.0, now)).unit_vectors()[0]
    fixed = star.at_epoch(2026.0).unit_vectors()[0]
    assert float(((resolved - rendered) ** 2).sum()) ** 0.5 < 0.05 * 5.3 * arcsec + 1e-9
    assert float(((fixed - rendered) ** 2).sum()) ** 0.5 > 4.0 * 5.3 * arcsec
