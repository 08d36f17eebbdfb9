# SPDX-License-Identifier: Apache-2.0
"""
Pixel-integrated elliptical Gaussian: the fit model of an astigmatic (elongated, not smeared) PSF.

The round Gaussian at the minor axis, fitted to a star elongated 1.5:1 at an angle to the
pixel grid, pulls its centre toward the pixel centre by an amount that depends on the
sub-pixel phase: an elliptical PSF of sigma 0.78 x 0.46 px at 30 degrees came out at 1.2-1.3x
the Cramer-Rao bound. With the frame's estimated shape (psf_estimate: the stars' median
moments) as the model, the same stars are at 1.0-1.04x. The shape is fixed per frame; each
star's fit is x, y and flux (`fit_elliptical`: compiled; the same Gauss-Newton as
empirical_psf.fit_empirical, which takes any model with `sample` and is its reference).

Pixel integral: across x analytic (given y, x is Gaussian with the conditional mean and
variance), along y by Gauss-Legendre nodes (Y_NODES).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar

import math

import numpy as np
from numba import njit
from scipy.special import erf

from .empirical_psf import STEP_DONE_PX
from .kernels import invert_3x3

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


def fit_elliptical(psf: EllipticalGaussianPsf, win, valid, col0, row0, x0, y0, flux0, noise: float, gain: float,
                   iterations: int = 8):
    """
    Fit `psf` to n windows: (x, y, flux, cov (n, 2, 2), flux_var, converged), as empirical_psf.fit_empirical.

    Windows: background-subtracted data [ADU] (n, S, S) with their valid masks, top-left
    pixel (col0, row0) [px]; starts x0, y0 [px], flux0 [ADU]; pixel noise [ADU], gain [e-/ADU].
    """
    cxx, cxy, cyy = psf._covariance
    n = np.asarray(x0).size
    return _fit_windows(np.ascontiguousarray(win, np.float64), np.ascontiguousarray(valid, np.bool_),
                        np.asarray(col0, np.float64).reshape(n), np.asarray(row0, np.float64).reshape(n),
                        np.asarray(x0, np.float64).reshape(n), np.asarray(y0, np.float64).reshape(n),
                        np.asarray(flux0, np.float64).reshape(n), cxx, cxy, cyy, float(noise), float(gain),
                        int(iterations), _NODES, _WEIGHTS, STEP_DONE_PX)


@njit(cache=True, fastmath=False)
def _fit_windows(data, valid, col0, row0, x0, y0, flux0, cxx, cxy, cyy, noise, gain, iterations, nodes, weights,
                 step_done):
    n, size, _ = data.shape
    slope = cxy / cyy
    spread = math.sqrt(max(cxx - cxy * slope, 1e-12))
    inv_root2, inv_root_2pi = 1.0 / math.sqrt(2.0), 1.0 / math.sqrt(2.0 * math.pi)
    x, y, flux = x0.copy(), y0.copy(), np.maximum(flux0.copy(), 1e-9)
    cov = np.full((n, 2, 2), np.nan)
    flux_var = np.full(n, np.nan)
    converged = np.zeros(n, np.bool_)
    normal, inv = np.empty((3, 3)), np.empty((3, 3))
    grad = np.empty(3)
    value, grad_x, grad_y = np.empty((size, size)), np.empty((size, size)), np.empty((size, size))
    cdf, pdf = np.empty(size + 1), np.empty(size + 1)
    for s in range(n):
        ok = False
        for _ in range(iterations):
            # The model on the window: per row and y node, the x integrals share their pixel edges.
            value[:, :] = 0.0
            grad_x[:, :] = 0.0
            grad_y[:, :] = 0.0
            for i in range(size):
                dy = row0[s] + i - y[s]
                for k in range(nodes.size):
                    yy = dy + nodes[k]
                    marginal = weights[k] * math.exp(-0.5 * yy * yy / cyy) * inv_root_2pi / math.sqrt(cyy)
                    for e in range(size + 1):
                        t = (col0[s] + e - 0.5 - x[s] - slope * yy) / spread
                        cdf[e] = 0.5 * math.erf(t * inv_root2)
                        pdf[e] = math.exp(-0.5 * t * t) * inv_root_2pi / spread
                    for j in range(size):
                        across = cdf[j + 1] - cdf[j]
                        edge = pdf[j + 1] - pdf[j]
                        value[i, j] += marginal * across
                        grad_x[i, j] += marginal * edge
                        grad_y[i, j] += marginal * (-yy / cyy * across - slope * edge)
            normal[:, :] = 0.0
            grad[:] = 0.0
            f = flux[s]
            for i in range(size):
                for j in range(size):
                    if not valid[s, i, j]:
                        continue
                    model = f * value[i, j]
                    weight = 1.0 / (max(model, 0.0) / gain + noise * noise)
                    j0, j1, j2 = -f * grad_x[i, j], -f * grad_y[i, j], value[i, j]
                    resid = weight * (data[s, i, j] - model)
                    grad[0] += j0 * resid
                    grad[1] += j1 * resid
                    grad[2] += j2 * resid
                    normal[0, 0] += weight * j0 * j0
                    normal[0, 1] += weight * j0 * j1
                    normal[0, 2] += weight * j0 * j2
                    normal[1, 1] += weight * j1 * j1
                    normal[1, 2] += weight * j1 * j2
                    normal[2, 2] += weight * j2 * j2
            for a in range(3):
                for b in range(a):
                    normal[a, b] = normal[b, a]
            if not invert_3x3(normal, inv):
                ok = False
                break
            i00, i01, i02 = inv[0, 0], inv[0, 1], inv[0, 2]
            i10, i11, i12 = inv[1, 0], inv[1, 1], inv[1, 2]
            i20, i21, i22 = inv[2, 0], inv[2, 1], inv[2, 2]
            cov[s, 0, 0], cov[s, 0, 1], cov[s, 1, 0], cov[s, 1, 1] = i00, i01, i10, i11
            flux_var[s] = i22
            ok = True
            step_x = i00 * grad[0] + i01 * grad[1] + i02 * grad[2]
            step_y = i10 * grad[0] + i11 * grad[1] + i12 * grad[2]
            step_f = i20 * grad[0] + i21 * grad[1] + i22 * grad[2]
            shift = math.sqrt(step_x * step_x + step_y * step_y)
            scale = 0.5 / shift if shift > 0.5 else 1.0
            x[s] += step_x * scale
            y[s] += step_y * scale
            flux[s] = max(flux[s] + step_f, 1e-9)
            if shift < step_done:
                break
        moved = math.hypot(x[s] - x0[s], y[s] - y0[s])
        converged[s] = (ok and math.isfinite(x[s]) and math.isfinite(y[s]) and moved < 2.0 and flux[s] > 1e-6
                        and flux_var[s] > 0 and cov[s, 0, 0] > 0 and cov[s, 1, 1] > 0
                        and math.isfinite(cov[s, 0, 1]))
    return x, y, flux, cov, flux_var, converged
