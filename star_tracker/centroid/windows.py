# SPDX-License-Identifier: Apache-2.0
"""Pixel windows around spots, as the PSF fits take them: gather_windows, PsfWindows, PsfStart."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np


def gather_windows(image: np.ndarray, col0: np.ndarray, row0: np.ndarray, size: int | tuple[int, int]):
    """
    Return (n, rows, cols) float windows with top-left pixel (col0, row0) [px], and a mask.

    size: an int for square windows or (rows, cols); the mask holds the pixels inside the
    image (outside ones read as 0).
    """
    height, width = image.shape
    size_r, size_c = (size, size) if np.isscalar(size) else size
    rows = np.asarray(row0, np.int64)[:, None] + np.arange(size_r)[None, :]
    cols = np.asarray(col0, np.int64)[:, None] + np.arange(size_c)[None, :]
    inside = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    data = image[np.clip(rows, 0, height - 1)[:, :, None], np.clip(cols, 0, width - 1)[:, None, :]]
    return np.where(inside, data.astype(np.float64), 0.0), inside


class PsfWindows(NamedTuple):
    """
    n windows of background-subtracted data (n, S, S) [ADU].

    Valid (n, S, S) bool, the usable pixels; col0, row0 (n,) the top-left pixel [px].
    """

    data: np.ndarray
    valid: np.ndarray
    col0: np.ndarray
    row0: np.ndarray


class PsfStart(NamedTuple):
    """Starting values of M sources per window, (n, M) each (or (n,) for M = 1): x, y [px], flux [ADU]."""

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
