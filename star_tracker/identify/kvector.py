# SPDX-License-Identifier: Apache-2.0
"""
k-vector range search (Mortari): O(1) lookup of all sorted values inside [lo, hi].

For n sorted values s, a line z(i) = m i + q through (0, s_0 - xi) and (n-1, s_{n-1} + xi)
is stored with k[i] = number of values <= z(i). A query [lo, hi] maps to the line's indices
j_lo = floor((lo - q)/m), j_hi = ceil((hi - q)/m); the answer lies in s[k[j_lo - 1] : k[j_hi]],
which contains at most a few extra values at each end; those are trimmed exactly.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit


class KVector(NamedTuple):
    """
    sorted_values: ascending (n,); k: (n,) counts; slope m and intercept q of z(i).

    A record of arrays and floats, so compiled code can take it whole.
    """

    sorted_values: np.ndarray
    k: np.ndarray
    slope: float
    intercept: float

    @staticmethod
    def build(sorted_values: np.ndarray) -> "KVector":
        s = np.asarray(sorted_values, dtype=float)
        n = s.size
        if n < 2:
            raise ValueError("k-vector needs at least two values")
        if np.any(np.diff(s) < 0):
            raise ValueError("k-vector values must be sorted ascending")
        xi = np.finfo(float).eps * max(abs(s[0]), abs(s[-1]), 1.0) * n
        slope = (s[-1] - s[0] + 2 * xi) / (n - 1)
        intercept = s[0] - xi
        z = slope * np.arange(n) + intercept
        k = np.searchsorted(s, z, side="right").astype(np.int64)
        return KVector(s, k, float(slope), float(intercept))

    def range(self, lo: float, hi: float) -> tuple[int, int]:
        """Half-open index range [start, stop) of values with lo <= value <= hi."""
        n = self.k.size
        if not lo <= hi or hi < self.sorted_values[0] or lo > self.sorted_values[-1]:  # NaN too
            return 0, 0
        lo, hi = max(lo, self.sorted_values[0]), min(hi, self.sorted_values[-1])  # infinite bounds
        j_lo = int(np.floor((lo - self.intercept) / self.slope))
        j_hi = int(np.ceil((hi - self.intercept) / self.slope))
        # z(j_lo - 1) < lo strictly, so every value counted by k[j_lo - 1] is below lo.
        start = int(self.k[min(j_lo - 1, n - 1)]) if j_lo >= 1 else 0
        stop = int(self.k[j_hi]) if 0 <= j_hi < n else n
        window = self.sorted_values[start:stop]
        # Trim the few values of the window that fall outside [lo, hi].
        return start + int(np.searchsorted(window, lo, "left")), start + int(np.searchsorted(window, hi, "right"))


@njit(cache=True)
def kvector_window(k, slope, intercept, first, last, lo, hi):
    """
    Compiled `KVector.range` without the final trim.

    [start, stop) of the k-vector (k, slope, intercept) over sorted values from `first` to
    `last` that holds every value in [lo, hi] (and a few beyond; (0, 0) when the window
    misses the values).
    """
    n = k.size
    if hi < lo or hi < first or lo > last:
        return 0, 0
    j_lo = int(math.floor((lo - intercept) / slope))
    j_hi = int(math.ceil((hi - intercept) / slope))
    start = k[min(j_lo - 1, n - 1)] if j_lo >= 1 else 0
    stop = k[j_hi] if 0 <= j_hi < n else n
    return start, stop
