# SPDX-License-Identifier: Apache-2.0
"""Small dense systems of the compiled PSF fits (numba): a 3x3 inverse by cofactors, an SPD solve by Cholesky."""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, fastmath=False)
def invert_3x3(a: np.ndarray, out: np.ndarray) -> bool:
    """Write the inverse of the 3x3 matrix `a` into `out` by cofactors; False (out unchanged) when singular."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    if not (det != 0.0 and math.isfinite(det)):
        return False
    out[0, 0], out[1, 0], out[2, 0] = c00 / det, c01 / det, c02 / det
    out[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) / det
    out[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) / det
    out[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) / det
    out[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) / det
    out[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) / det
    out[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) / det
    return True


@njit(cache=True)
def solve_spd(normal: np.ndarray, rhs: np.ndarray, out: np.ndarray) -> bool:
    """
    Solve out = normal^-1 rhs by Cholesky (normal symmetric positive definite, overwritten by its factor).

    False when it is not positive definite.
    """
    n = rhs.size
    for j in range(n):
        d = normal[j, j]
        for k in range(j):
            d -= normal[j, k] * normal[j, k]
        if not (d > 0.0 and math.isfinite(d)):
            return False
        d = math.sqrt(d)
        normal[j, j] = d
        for i in range(j + 1, n):
            v = normal[i, j]
            for k in range(j):
                v -= normal[i, k] * normal[j, k]
            normal[i, j] = v / d
    for i in range(n):
        v = rhs[i]
        for k in range(i):
            v -= normal[i, k] * out[k]
        out[i] = v / normal[i, i]
    for i in range(n - 1, -1, -1):
        v = out[i]
        for k in range(i + 1, n):
            v -= normal[k, i] * out[k]
        out[i] = v / normal[i, i]
    return True
