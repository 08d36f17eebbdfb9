# SPDX-License-Identifier: Apache-2.0
"""
Double Gaussian: a core and a wider halo on one centre, the fit model of a PSF with wings.

An undersampled PSF with broad wings (a Moffat beta 3 of FWHM 0.94 px) fitted with one
Gaussian has its centre pulled with the sub-pixel phase: 1.6-2.3x the Cramer-Rao bound at
SNR 65-170, though each fit's chi^2 alone rarely flags it. Two Gaussians on one centre,
the halo's share and both widths fitted to the frame's bright stars, describe it within 1 %
of the peak; with that shape fixed, each star's fit (x, y, flux) is at 1.04-1.15x. Both
components integrate over a pixel exactly (erf), so the compiled single-PSF fit
(kernels.fit_single_psf) carries the halo.

The frame's shape: its bright round stars' windows, positions and fluxes from the one-Gaussian
fit; the three shape values by least squares with each star's flux solved linearly, the stars
refitted with the shape, the shape fitted again (SHAPE_PASSES).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.optimize import least_squares

from .psf_fit import PsfFit, PsfSettings, PsfStart, PsfWindows, pixel_integrated_profile

SHAPE_PASSES = 2  # shape from the one-Gaussian positions, stars refitted, shape again
SHAPE_STARS = 30  # the brightest this many stars fix the shape (more add time, not accuracy)
MAX_HALO_RATIO = 6.0  # halo 1-sigma at most this x the core's
MIN_HALO_RATIO = 1.05  # ... and at least this: two equal widths are one Gaussian


@dataclass(frozen=True)
class DoubleGaussianPsf:
    """Unit-flux PSF: (1 - halo_share) N(core_px) + halo_share N(halo_px), round, 1-sigma widths [px]."""

    core_px: float
    halo_px: float
    halo_share: float
    label: ClassVar[str] = "core_halo"  # its name in Spots.fit_model

    def sample(self, dx: np.ndarray, dy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Share of the flux in the pixel centred at offset (dx, dy) [px] from the star, and its derivatives [1/px]."""
        value, grad_x, grad_y = 0.0, 0.0, 0.0
        for sigma, share in ((self.core_px, 1.0 - self.halo_share), (self.halo_px, self.halo_share)):
            # pixel_integrated_profile's derivative is along the centre: along the offset it is the negative.
            px, dpx = pixel_integrated_profile(np.asarray(dx) - 0.5, 0.0, sigma)
            py, dpy = pixel_integrated_profile(np.asarray(dy) - 0.5, 0.0, sigma)
            value = value + share * px * py
            grad_x = grad_x - share * dpx * py
            grad_y = grad_y - share * px * dpy
        return value, grad_x, grad_y

    def window_shares(self, col0, row0, x, y, size: int) -> np.ndarray:
        """(n, size, size) shares of the flux of stars at (x, y) [px] in windows with top-left pixel (col0, row0)."""
        steps = np.arange(size) - 0.5
        out = 0.0
        for sigma, share in ((self.core_px, 1.0 - self.halo_share), (self.halo_px, self.halo_share)):
            px, _ = pixel_integrated_profile(np.asarray(col0, float)[:, None] + steps, np.asarray(x, float)[:, None],
                                             sigma)
            py, _ = pixel_integrated_profile(np.asarray(row0, float)[:, None] + steps, np.asarray(y, float)[:, None],
                                             sigma)
            out = out + share * py[:, :, None] * px[:, None, :]
        return out

    def fit(self, windows: PsfWindows, start: PsfStart, noise: float, gain: float, iterations: int = 10) -> PsfFit:
        """Fit one star of this shape per window (x, y, flux; kernels.fit_single_psf); start (n,) arrays."""
        from .kernels import fit_single_psf

        compiled = PsfWindows(np.ascontiguousarray(windows.data, np.float64),
                              np.ascontiguousarray(windows.valid, np.bool_),
                              np.asarray(windows.col0, np.float64), np.asarray(windows.row0, np.float64))
        settings = PsfSettings(float(self.core_px), float(noise), float(gain), int(iterations), float(self.halo_px),
                               float(self.halo_share))
        x, y, flux, cov, flux_var, ok = fit_single_psf(
            compiled, PsfStart(*(np.asarray(v, np.float64).copy() for v in start)), settings)
        return PsfFit(x[:, None], y[:, None], flux[:, None], cov[:, None], ok[:, None], flux_var[:, None])


def estimate_double_gaussian(windows: PsfWindows, x, y, sigma_px: float, noise: float, gain: float
                             ) -> DoubleGaussianPsf | None:
    """
    Return the core/halo shape that best describes the stars in `windows` (bright, round, isolated), or None.

    x, y [px]: their positions from the one-Gaussian fit of 1-sigma sigma_px [px], the start.
    None when the fit fails or settles on one Gaussian (no halo share, or equal widths).
    """
    data = np.where(windows.valid, windows.data, 0.0)
    # Unweighted: the core, where the centre is measured, counts as its pixel values say (at
    # high SNR the Poisson weights favour the wings, and the core fitted worse pulls the centres).
    weight = np.where(windows.valid, 1.0, 0.0)
    size = data.shape[1]
    x, y = np.asarray(x, float).copy(), np.asarray(y, float).copy()
    # Unbounded values (MINPACK's Levenberg-Marquardt): log core [px], logit of the halo ratio's
    # place in [MIN_HALO_RATIO, MAX_HALO_RATIO], logit of the halo share.
    start_ratio = (2.0 - MIN_HALO_RATIO) / (MAX_HALO_RATIO - MIN_HALO_RATIO)
    shape = np.array([np.log(0.8 * sigma_px), np.log(start_ratio / (1.0 - start_ratio)), 0.0])

    def unpack(p) -> DoubleGaussianPsf:
        core = float(np.exp(np.clip(p[0], np.log(0.1), np.log(20.0))))
        ratio = MIN_HALO_RATIO + (MAX_HALO_RATIO - MIN_HALO_RATIO) / (1.0 + float(np.exp(-np.clip(p[1], -30, 30))))
        return DoubleGaussianPsf(core, core * ratio, 1.0 / (1.0 + float(np.exp(-np.clip(p[2], -30, 30)))))

    psf = None
    for _ in range(SHAPE_PASSES):
        def residuals(p):
            share = unpack(p).window_shares(windows.col0, windows.row0, x, y, size)
            flux = (weight * share * data).sum(axis=(1, 2)) / np.maximum((weight * share * share).sum(axis=(1, 2)),
                                                                         1e-300)
            return (np.sqrt(weight) * (data - flux[:, None, None] * share)).ravel()

        result = least_squares(residuals, shape, method="lm", xtol=1e-4, ftol=1e-6, max_nfev=60)
        if not np.all(np.isfinite(result.x)):
            return None
        shape = result.x
        psf = unpack(shape)
        start = PsfStart(x, y, np.maximum(data.sum(axis=(1, 2)), 1.0))
        refit = psf.fit(windows, start, noise, gain)
        ok = refit.converged[:, 0]
        x, y = np.where(ok, refit.x[:, 0], x), np.where(ok, refit.y[:, 0], y)
    if psf is None or not (0.02 <= psf.halo_share <= 0.98) or psf.halo_px < 1.1 * psf.core_px:
        return None
    return psf
