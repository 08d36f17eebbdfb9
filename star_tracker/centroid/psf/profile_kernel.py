# SPDX-License-Identifier: Apache-2.0
"""
The pixel-integrated 1-D Gaussian, compiled (numba): the profile every compiled Gaussian fit samples.

A circular Gaussian PSF integrated over a square pixel is the product of two such profiles,
one along x and one along y.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_INV_ROOT2 = 1.0 / math.sqrt(2.0)
_INV_ROOT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


@njit(cache=True, fastmath=False)
def gaussian_profile(lo: float, centre: float, sigma: float, size: int, prob: np.ndarray, deriv: np.ndarray) -> None:
    """
    Fraction of a 1-D Gaussian in pixels [lo + k, lo + k + 1) and its derivative with respect to the centre.

    For k = 0..size-1 (gaussian_fit.pixel_integrated_profile, compiled).
    """
    for k in range(size):
        a = (lo + k - centre) / sigma
        b = a + 1.0 / sigma
        prob[k] = 0.5 * (math.erf(b * _INV_ROOT2) - math.erf(a * _INV_ROOT2))
        deriv[k] = (math.exp(-0.5 * a * a) - math.exp(-0.5 * b * b)) * (_INV_ROOT_2PI / sigma)


@njit(cache=True, fastmath=False)
def gaussian_profile_with_width(lo: float, centre: float, sigma: float, size: int, prob: np.ndarray,
                                d_centre: np.ndarray, d_sigma: np.ndarray) -> None:
    """gaussian_profile plus the derivative of each pixel's fraction with respect to sigma [1/px]."""
    for k in range(size):
        a = (lo + k - centre) / sigma
        b = a + 1.0 / sigma
        pa = math.exp(-0.5 * a * a) * _INV_ROOT_2PI
        pb = math.exp(-0.5 * b * b) * _INV_ROOT_2PI
        prob[k] = 0.5 * (math.erf(b * _INV_ROOT2) - math.erf(a * _INV_ROOT2))
        d_centre[k] = (pa - pb) / sigma
        d_sigma[k] = (a * pa - b * pb) / sigma
