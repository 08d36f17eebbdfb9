# SPDX-License-Identifier: Apache-2.0
"""
Blooming: charge above a pixel's full well spills along its CCD column.

In each column, every run of pixels over the full well keeps the full well and sends its
excess half up and half down the column; the spill fills the next pixels to the full well one
after the other (passing through pixels already full) and what reaches the end of the column
is lost (drained at the register). Without blooming the full well simply clips.
"""
from __future__ import annotations

import numpy as np


def _spill(column: np.ndarray, start: int, step: int, charge: float, full_well: float) -> None:
    """Fill column pixels from `start` in direction `step` (+1 down, -1 up) with `charge` [e-], to the full well."""
    rows = np.arange(start, column.size) if step > 0 else np.arange(start, -1, -1)
    room = np.maximum(full_well - column[rows], 0.0)
    before = np.cumsum(room) - room  # room in the pixels nearer the run
    column[rows] += np.clip(charge - before, 0.0, room)


def bloom_columns(electrons: np.ndarray, full_well: float) -> None:
    """
    Spill the charge above full_well [e-] of `electrons` (H, W) along the columns, in place.

    Only columns holding a pixel over the full well and one under it are worked on (a column
    full from end to end just clips).
    """
    if not electrons.max() > full_well:
        return
    over = electrons > full_well
    columns = np.flatnonzero(over.any(axis=0) & ~over.all(axis=0))
    for c in columns:
        column = electrons[:, c].astype(np.float64)
        above = np.flatnonzero(column > full_well)
        breaks = np.flatnonzero(np.diff(above) > 1)
        for first, last in zip(np.r_[above[0], above[breaks + 1]], np.r_[above[breaks], above[-1]]):
            excess = float(np.sum(column[first:last + 1] - full_well))
            column[first:last + 1] = np.minimum(column[first:last + 1], full_well)
            _spill(column, first - 1, -1, 0.5 * excess, full_well)
            _spill(column, last + 1, 1, 0.5 * excess, full_well)
        electrons[:, c] = column
    np.minimum(electrons, full_well, out=electrons)
