# SPDX-License-Identifier: Apache-2.0
"""
Pixel-integrated elliptical Gaussian: the fit model of an astigmatic (elongated, not smeared) PSF.

The round Gaussian at the minor axis, fitted to a star elongated 1.5:1 at an angle to the
pixel grid, pulls its centre toward the pixel centre by an amount that depends on the
sub-pixel phase: an elliptical PSF of sigma 0.78 x 0.46 px at 30 degrees came out at 1.2-1.3x
the Cramer-Rao bound. With the frame's estimated shape (psf.estimate: the stars' median
moments) as the model, the same stars are at 1.0-1.04x. The shape is fixed per frame; each
star's fit is x, y and flux (`fit_elliptical`: compiled in elliptical_fit_kernel; the same Gauss-Newton as
psf.empirical.fit_empirical, which takes any model with `sample` and is its reference).

Pixel integral: across x analytic (given y, x is Gaussian with the conditional mean and
variance), along y by Gauss-Legendre nodes (Y_NODES).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar

import numpy as np
from scipy.special import erf

from ..windows import PsfStart, PsfWindows
from .elliptical_fit_kernel import EllipseShape, EllipticalFitSettings, fit_windows
from .empirical import STEP_DONE_PX

Y_NODES = 4  # Gauss-Legendre nodes across a pixel in y: within 1e-4 of the peak down to sigma 0.35 px
_ROOT2 = np.sqrt(2.0)
_INV_ROOT_2PI = 1.0 / np.sqrt(2.0 * np.pi)
_NODES, _WEIGHTS = (0.5 * a for a in np.polynomial.legendre.leggauss(Y_NODES))


@dataclass(frozen=True)
class EllipticalGaussianPsf:
    """
    Pixel-integrated elliptical Gaussian of unit flux.

    1-sigma widths major_px >= minor_px [px]; major axis at angle_rad [rad] from image +x
    toward +y (the image frame: x right, y down).
    """

    major_px: float
    minor_px: float
    angle_rad: float
    label: ClassVar[str] = "elliptical"  # its name in Spots.fit_model

    @cached_property
    def _covariance(self) -> tuple[float, float, float]:
        """(Cxx, Cxy, Cyy) [px^2] of the density."""
        c, s = np.cos(self.angle_rad), np.sin(self.angle_rad)
        a2, b2 = self.major_px ** 2, self.minor_px ** 2
        return a2 * c * c + b2 * s * s, (a2 - b2) * c * s, a2 * s * s + b2 * c * c

    def sample(self, dx: np.ndarray, dy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        Share of the flux in the pixel centred at offset (dx, dy) [px] from the star, and its derivatives along dx, dy.

        Any (equal) shapes; the derivatives are [1/px].
        """
        cxx, cxy, cyy = self._covariance
        slope = cxy / cyy  # conditional mean of x given y, per px of y
        spread = np.sqrt(max(cxx - cxy * slope, 1e-12))  # conditional 1-sigma of x given y [px]
        dx, dy = np.asarray(dx, float), np.asarray(dy, float)
        value, grad_x, grad_y = np.zeros(dx.shape), np.zeros(dx.shape), np.zeros(dx.shape)
        for t, w in zip(_NODES, _WEIGHTS):
            y = dy + t
            marginal = np.exp(-0.5 * y * y / cyy) * (_INV_ROOT_2PI / np.sqrt(cyy))
            hi = (dx + 0.5 - slope * y) / spread
            lo = (dx - 0.5 - slope * y) / spread
            across = 0.5 * (erf(hi / _ROOT2) - erf(lo / _ROOT2))
            edge = (np.exp(-0.5 * hi * hi) - np.exp(-0.5 * lo * lo)) * (_INV_ROOT_2PI / spread)
            value += w * marginal * across
            grad_x += w * marginal * edge
            grad_y += w * marginal * (-y / cyy * across - slope * edge)
        return value, grad_x, grad_y


def fit_elliptical(psf: EllipticalGaussianPsf, windows: PsfWindows, start: PsfStart, noise: float, gain: float,
                   iterations: int = 8):
    """
    Fit `psf` to n windows: (x, y, flux, cov (n, 2, 2), flux_var, converged), as empirical.fit_empirical.

    windows: background-subtracted data [ADU] (n, S, S) with their valid masks, top-left
    pixel (col0, row0) [px]; start: x, y [px], flux [ADU] (n,); pixel noise [ADU], gain [e-/ADU].
    """
    cxx, cxy, cyy = psf._covariance
    n = np.asarray(start.x).size
    windows = PsfWindows(np.ascontiguousarray(windows.data, np.float64),
                         np.ascontiguousarray(windows.valid, np.bool_),
                         np.asarray(windows.col0, np.float64).reshape(n),
                         np.asarray(windows.row0, np.float64).reshape(n))
    start = PsfStart(np.asarray(start.x, np.float64).reshape(n), np.asarray(start.y, np.float64).reshape(n),
                     np.asarray(start.flux, np.float64).reshape(n))
    return fit_windows(windows, start, EllipseShape(float(cxx), float(cxy), float(cyy), _NODES, _WEIGHTS),
                       EllipticalFitSettings(float(noise), float(gain), int(iterations), float(STEP_DONE_PX)))
