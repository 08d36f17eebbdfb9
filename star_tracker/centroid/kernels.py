"""Compiled inner loops of the centroider (numba): the per-spot work that is too small for
numpy's per-call overhead to pay off. Compiled on first use and cached on disk next to this
module (or in NUMBA_CACHE_DIR)."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_INV_ROOT2 = 1.0 / math.sqrt(2.0)
_INV_ROOT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


@njit(cache=True, fastmath=False)
def _profile(lo: float, centre: float, sigma: float, size: int, prob: np.ndarray, deriv: np.ndarray) -> None:
    """Fraction of a 1-D Gaussian in pixels [lo + k, lo + k + 1) and its derivative with respect
    to the centre, k = 0..size-1 (see psf_fit.pixel_integrated_profile)."""
    for k in range(size):
        a = (lo + k - centre) / sigma
        b = a + 1.0 / sigma
        prob[k] = 0.5 * (math.erf(b * _INV_ROOT2) - math.erf(a * _INV_ROOT2))
        deriv[k] = (math.exp(-0.5 * a * a) - math.exp(-0.5 * b * b)) * (_INV_ROOT_2PI / sigma)


@njit(cache=True, fastmath=False)
def fit_single_psf(data, valid, col0, row0, x0, y0, flux0, sigma, noise, gain, iterations):
    """One pixel-integrated Gaussian PSF per window: the same weighted Gauss-Newton as
    psf_fit.fit_psf_windows with M = 1 (1 px trust region, 1e-9 relative damping, stop when
    the position step is below 1 % of its sigma, covariance from the last step's inverse).
    data, valid: (n, S, S); col0, row0, x0, y0, flux0: (n,). Returns x, y, flux (n,),
    cov (n, 2, 2), flux_var (n,), converged (n,)."""
    n, size, _ = data.shape
    x, y, flux = x0.copy(), y0.copy(), np.maximum(flux0.copy(), 1e-9)
    cov = np.full((n, 2, 2), np.nan)
    flux_var = np.full(n, np.nan)
    converged = np.zeros(n, np.bool_)
    px = np.empty(size)
    dpx = np.empty(size)
    py = np.empty(size)
    dpy = np.empty(size)
    normal = np.empty((3, 3))
    inv = np.empty((3, 3))
    grad = np.empty(3)
    jac = np.empty(3)
    for s in range(n):
        for _ in range(iterations):
            _profile(col0[s] - 0.5, x[s], sigma, size, px, dpx)
            _profile(row0[s] - 0.5, y[s], sigma, size, py, dpy)
            normal[:, :] = 0.0
            grad[:] = 0.0
            f = flux[s]
            for i in range(size):
                for j in range(size):
                    if not valid[s, i, j]:
                        continue
                    shape = py[i] * px[j]
                    model = f * shape
                    weight = 1.0 / (max(model, 0.0) / gain + noise * noise)
                    jac[0] = f * py[i] * dpx[j]
                    jac[1] = f * dpy[i] * px[j]
                    jac[2] = shape
                    resid = data[s, i, j] - model
                    for a in range(3):
                        wa = weight * jac[a]
                        grad[a] += wa * resid
                        for b in range(a, 3):
                            normal[a, b] += wa * jac[b]
            for a in range(3):
                for b in range(a):
                    normal[a, b] = normal[b, a]
                normal[a, a] += 1e-9 * abs(normal[a, a]) + 1e-300
            # Inverse by cofactors (symmetric 3x3).
            c00 = normal[1, 1] * normal[2, 2] - normal[1, 2] * normal[2, 1]
            c01 = normal[1, 2] * normal[2, 0] - normal[1, 0] * normal[2, 2]
            c02 = normal[1, 0] * normal[2, 1] - normal[1, 1] * normal[2, 0]
            det = normal[0, 0] * c00 + normal[0, 1] * c01 + normal[0, 2] * c02
            if not (det != 0.0 and math.isfinite(det)):
                break
            inv[0, 0], inv[1, 0], inv[2, 0] = c00 / det, c01 / det, c02 / det
            inv[0, 1] = (normal[0, 2] * normal[2, 1] - normal[0, 1] * normal[2, 2]) / det
            inv[0, 2] = (normal[0, 1] * normal[1, 2] - normal[0, 2] * normal[1, 1]) / det
            inv[1, 1] = (normal[0, 0] * normal[2, 2] - normal[0, 2] * normal[2, 0]) / det
            inv[1, 2] = (normal[0, 2] * normal[1, 0] - normal[0, 0] * normal[1, 2]) / det
            inv[2, 1] = (normal[0, 1] * normal[2, 0] - normal[0, 0] * normal[2, 1]) / det
            inv[2, 2] = (normal[0, 0] * normal[1, 1] - normal[0, 1] * normal[1, 0]) / det
            step_x = inv[0, 0] * grad[0] + inv[0, 1] * grad[1] + inv[0, 2] * grad[2]
            step_y = inv[1, 0] * grad[0] + inv[1, 1] * grad[1] + inv[1, 2] * grad[2]
            step_f = inv[2, 0] * grad[0] + inv[2, 1] * grad[1] + inv[2, 2] * grad[2]
            step_x = min(max(step_x, -1.0), 1.0)
            step_y = min(max(step_y, -1.0), 1.0)
            x[s] += step_x
            y[s] += step_y
            flux[s] = max(flux[s] + step_f, 1e-9)
            cov[s, 0, 0], cov[s, 0, 1], cov[s, 1, 0], cov[s, 1, 1] = inv[0, 0], inv[0, 1], inv[1, 0], inv[1, 1]
            flux_var[s] = inv[2, 2]
            if (step_x * step_x <= max(1e-4 * abs(inv[0, 0]), 1e-10)
                    and step_y * step_y <= max(1e-4 * abs(inv[1, 1]), 1e-10)):
                break
        converged[s] = (math.isfinite(cov[s, 0, 0]) and math.isfinite(cov[s, 1, 1]) and math.isfinite(cov[s, 0, 1])
                        and cov[s, 0, 0] > 0 and cov[s, 1, 1] > 0 and math.isfinite(x[s]) and math.isfinite(y[s])
                        and col0[s] + 0.5 < x[s] < col0[s] + size - 1.5 and row0[s] + 0.5 < y[s] < row0[s] + size - 1.5)
    return x, y, flux, cov, flux_var, converged


def warm_up() -> None:
    """Compile (or load from the cache) every kernel now, not on the first frame."""
    data = np.zeros((1, 7, 7))
    data[0, 3, 3] = 100.0
    fit_single_psf(data, np.ones((1, 7, 7), np.bool_), np.zeros(1), np.zeros(1), np.full(1, 3.0), np.full(1, 3.0),
                   np.full(1, 100.0), 1.0, 1.0, 1.0, 5)
