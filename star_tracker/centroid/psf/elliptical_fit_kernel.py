# SPDX-License-Identifier: Apache-2.0
"""
The elliptical Gaussian PSF fit, compiled (numba): elliptical.fit_elliptical's Gauss-Newton.

The model on each window: across x analytic (given y, x is Gaussian with the conditional mean
and variance), along y by Gauss-Legendre nodes; per row and node the x integrals share their
pixel edges.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ..windows import PsfStart, PsfWindows
from .matrix_kernel import invert_3x3


class EllipseShape(NamedTuple):
    """
    The PSF's fixed shape.

    cxx, cxy, cyy: the density's covariance [px^2]; nodes, weights (k,) float64: Gauss-Legendre
    nodes across a pixel in y (offsets in [-0.5, 0.5] px) and weights summing to 1.
    """

    cxx: float
    cxy: float
    cyy: float
    nodes: np.ndarray
    weights: np.ndarray


class EllipticalFitSettings(NamedTuple):
    """noise: 1-sigma pixel noise [ADU]; gain [e-/ADU]; iterations: most steps; step_done_px: converged below [px]."""

    noise: float
    gain: float
    iterations: int
    step_done_px: float


@njit(cache=True, fastmath=False)
def fit_windows(windows, start, shape, settings):
    """
    Fit the elliptical Gaussian `shape` (x, y and flux per star) to each window by weighted Gauss-Newton.

    windows: PsfWindows (data float64 (n, S, S) background-subtracted [ADU], valid bool, col0,
    row0 float64 (n,) top-left pixels [px]); start: PsfStart of (n,) float64 arrays (x, y
    [px], flux [ADU]); shape: EllipseShape; settings: EllipticalFitSettings. A step is capped
    at 0.5 px; a star converges when its step is below settings.step_done_px, it moved < 2 px
    from its start and its covariance is positive. Returns x, y, flux (n,), cov (n, 2, 2)
    [px^2], flux_var (n,) [ADU^2], converged (n,).
    """
    data, valid, col0, row0 = windows.data, windows.valid, windows.col0, windows.row0
    x0, y0, flux0 = start.x, start.y, start.flux
    cxx, cxy, cyy, nodes, weights = shape.cxx, shape.cxy, shape.cyy, shape.nodes, shape.weights
    noise, gain, iterations, step_done = settings.noise, settings.gain, settings.iterations, settings.step_done_px
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


def warm_up() -> None:
    """Compile (or load from the cache) the fit for the float64 windows elliptical.fit_elliptical passes."""
    data = np.zeros((1, 7, 7))
    data[0, 3, 3] = 100.0
    nodes, weights = (0.5 * a for a in np.polynomial.legendre.leggauss(4))
    fit_windows(PsfWindows(data, np.ones((1, 7, 7), np.bool_), np.zeros(1), np.zeros(1)),
                PsfStart(np.full(1, 3.0), np.full(1, 3.0), np.full(1, 100.0)),
                EllipseShape(2.0, 0.3, 1.2, nodes, weights), EllipticalFitSettings(1.0, 1.0, 8, 1e-3))
