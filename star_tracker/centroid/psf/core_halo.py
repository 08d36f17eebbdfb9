# SPDX-License-Identifier: Apache-2.0
"""
Core and halo: Gaussians of growing width on one centre, the fit model of a PSF with wings.

An undersampled PSF with broad wings (a Moffat beta 3 of FWHM 0.94 px) fitted with one
Gaussian has its centre pulled with the sub-pixel phase: 1.6-2.3x the Cramer-Rao bound at
SNR 65-170, though each fit's chi^2 alone rarely flags it. Fitted to that Moffat without
noise, a core and one halo Gaussian still pull the centre by 0.005 px RMS per axis (at
30000 e- 1.30x the bound), a core and two halo Gaussians by 0.0016 px (1.07x); with three,
a frame's stars no longer fix the shape (1.37x at 5000 e-). The shares and widths are
fitted to the frame's bright stars; every component integrates over a pixel exactly (erf),
so the compiled single-PSF fit (gaussian_fit_kernel.fit_single_psf) carries the halo.

The frame's shape: its bright round stars' windows, positions and fluxes from the one-Gaussian
fit; the shape values by least squares with each star's flux solved linearly, the stars
refitted with the shape, the shape fitted again (SHAPE_PASSES: the positions the shape is
fitted at converge over the passes; with two, 1.19x at 30000 e-).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.optimize import least_squares

from ..windows import PsfStart, PsfWindows
from .gaussian_fit import PsfFit, pixel_integrated_profile
from .gaussian_fit_kernel import PsfSettings, fit_single_psf

HALO_COMPONENTS = 2  # halo Gaussians beside the core
SHAPE_PASSES = 4  # shape from the one-Gaussian positions, stars refitted, shape again, ...
SHAPE_STARS = 30  # the brightest this many stars fix the shape (more add time, not accuracy)
MAX_HALO_RATIO = 6.0  # each halo Gaussian's 1-sigma at most this x the next narrower one's
MIN_HALO_RATIO = 1.05  # ... and at least this: two equal widths are one Gaussian
MIN_HALO_SHARE = 1e-3  # a halo Gaussian with less of the flux is dropped from the fitted shape
START_RATIO = 1.85  # the fit's start: each halo Gaussian this x wider than the next narrower one
START_SHARE_LOGIT = -1.0  # ... with a share of e^-1 against the core's 1 (0.21 of the flux each)


@dataclass(frozen=True)
class CoreHaloPsf:
    """
    Unit-flux PSF: (1 - sum(halo_share)) N(core_px) + sum_k halo_share[k] N(halo_px[k]), round.

    1-sigma widths [px]; no halo components: the round Gaussian of core_px.
    """

    core_px: float
    halo_px: tuple[float, ...] = ()
    halo_share: tuple[float, ...] = ()
    label: ClassVar[str] = "core_halo"  # its name in Spots.fit_model

    def components(self) -> list[tuple[float, float]]:
        """(1-sigma [px], share of the flux) of the core, then each halo Gaussian."""
        return [(self.core_px, 1.0 - float(sum(self.halo_share)))] + list(zip(self.halo_px, self.halo_share))

    def sample(self, dx: np.ndarray, dy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Share of the flux in the pixel centred at offset (dx, dy) [px] from the star, and its derivatives [1/px]."""
        value, grad_x, grad_y = 0.0, 0.0, 0.0
        for sigma, share in self.components():
            # pixel_integrated_profile's derivative is along the centre: along the offset it is the negative.
            px, dpx = pixel_integrated_profile(np.asarray(dx) - 0.5, 0.0, sigma)
            py, dpy = pixel_integrated_profile(np.asarray(dy) - 0.5, 0.0, sigma)
            value = value + share * px * py
            grad_x = grad_x - share * dpx * py
            grad_y = grad_y - share * px * dpy
        return value, grad_x, grad_y

    def window_shares(self, col0, row0, x, y, size: int) -> np.ndarray:
        """(n, size, size) shares of the flux of stars at (x, y) [px] in windows with top-left pixel (col0, row0)."""
        return self.shares_in(_ProfileCache(col0, row0, x, y, size))

    def shares_in(self, profiles: "_ProfileCache") -> np.ndarray:
        """Return the window shares of the stars `profiles` holds: each component's pixel shares times its share."""
        return sum(share * profiles(sigma) for sigma, share in self.components())

    def fit(self, windows: PsfWindows, start: PsfStart, noise: float, gain: float, iterations: int = 10) -> PsfFit:
        """Fit one star of this shape per window (x, y, flux; gaussian_fit_kernel.fit_single_psf); start (n,) arrays."""
        compiled = PsfWindows(np.ascontiguousarray(windows.data, np.float64),
                              np.ascontiguousarray(windows.valid, np.bool_),
                              np.asarray(windows.col0, np.float64), np.asarray(windows.row0, np.float64))
        settings = PsfSettings(float(self.core_px), float(noise), float(gain), int(iterations),
                               np.array(self.halo_px, np.float64), np.array(self.halo_share, np.float64))
        x, y, flux, cov, flux_var, ok = fit_single_psf(
            compiled, PsfStart(*(np.asarray(v, np.float64).copy() for v in start)), settings)
        return PsfFit(x[:, None], y[:, None], flux[:, None], cov[:, None], ok[:, None], flux_var[:, None])


def _shape(p: np.ndarray) -> CoreHaloPsf:
    """
    Return the CoreHaloPsf of the unbounded fit values p.

    log core [px]; per halo Gaussian the logit of its width ratio's place in [MIN_HALO_RATIO,
    MAX_HALO_RATIO] (to the next narrower one); per halo Gaussian the log of its share
    against the core's (the shares a softmax with the core's log fixed at 0).
    """
    halos = (p.size - 1) // 2
    core = float(np.exp(np.clip(p[0], np.log(0.1), np.log(20.0))))
    widths, width = [], core
    for value in p[1:1 + halos]:
        width *= MIN_HALO_RATIO + (MAX_HALO_RATIO - MIN_HALO_RATIO) / (1.0 + float(np.exp(-np.clip(value, -30, 30))))
        widths.append(width)
    logs = np.concatenate([[0.0], np.clip(p[1 + halos:], -30.0, 30.0)])
    weights = np.exp(logs - logs.max())
    shares = weights / weights.sum()
    return CoreHaloPsf(core, tuple(widths), tuple(float(s) for s in shares[1:]))


def _values(psf: CoreHaloPsf) -> np.ndarray:
    """Return the fit values of `psf` (_shape's inverse; width ratios kept inside their bounds)."""
    narrower = (psf.core_px,) + psf.halo_px[:-1]
    place = [(np.clip(w / n, MIN_HALO_RATIO * 1.001, MAX_HALO_RATIO * 0.999) - MIN_HALO_RATIO)
             / (MAX_HALO_RATIO - MIN_HALO_RATIO) for w, n in zip(psf.halo_px, narrower)]
    core_share = 1.0 - sum(psf.halo_share)
    return np.array([math.log(psf.core_px)] + [math.log(t / (1.0 - t)) for t in place]
                    + [math.log(a / core_share) for a in psf.halo_share])


def _without_dark_halos(psf: CoreHaloPsf) -> CoreHaloPsf:
    """`psf` without the halo Gaussians of less than MIN_HALO_SHARE of the flux (a wider PSF's wings may be one)."""
    halos = [(w, a) for w, a in zip(psf.halo_px, psf.halo_share) if a >= MIN_HALO_SHARE]
    return CoreHaloPsf(psf.core_px, tuple(w for w, _ in halos), tuple(a for _, a in halos))


def estimate_core_halo(windows: PsfWindows, x, y, sigma_px: float, noise: float, gain: float) -> CoreHaloPsf | None:
    """
    Return the core/halo shape that best describes the stars in `windows` (bright, round, isolated), or None.

    x, y [px]: their positions from the one-Gaussian fit of 1-sigma sigma_px [px], the start.
    None when the fit fails or settles on one Gaussian (no halo share, or no wider halo).
    """
    data = np.where(windows.valid, windows.data, 0.0)
    # Unweighted: the core, where the centre is measured, counts as its pixel values say (at
    # high SNR the Poisson weights favour the wings, and the core fitted worse pulls the centres).
    weight = np.where(windows.valid, 1.0, 0.0)
    size = data.shape[1]
    x, y = np.asarray(x, float).copy(), np.asarray(y, float).copy()
    start_ratio = (START_RATIO - MIN_HALO_RATIO) / (MAX_HALO_RATIO - MIN_HALO_RATIO)
    shape = np.concatenate([[np.log(0.8 * sigma_px)],
                            np.full(HALO_COMPONENTS, np.log(start_ratio / (1.0 - start_ratio))),
                            np.full(HALO_COMPONENTS, START_SHARE_LOGIT)])

    for _ in range(SHAPE_PASSES):
        products = _ProfileCache(windows.col0, windows.row0, x, y, size)

        def residuals(p):
            share = _shape(p).shares_in(products)
            flux = (weight * share * data).sum(axis=(1, 2)) / np.maximum((weight * share * share).sum(axis=(1, 2)),
                                                                         1e-300)
            return (np.sqrt(weight) * (data - flux[:, None, None] * share)).ravel()

        result = least_squares(residuals, shape, method="lm", xtol=1e-4, ftol=1e-6, max_nfev=40 * shape.size)
        if not np.all(np.isfinite(result.x)):
            return None
        psf = _without_dark_halos(_shape(result.x))
        if not psf.halo_px:
            return None  # one Gaussian
        shape = _values(psf)
        start = PsfStart(x, y, np.maximum(data.sum(axis=(1, 2)), 1.0))
        refit = psf.fit(windows, start, noise, gain)
        ok = refit.converged[:, 0]
        x, y = np.where(ok, refit.x[:, 0], x), np.where(ok, refit.y[:, 0], y)
    if not (0.02 <= sum(psf.halo_share) <= 0.98) or psf.halo_px[-1] < 1.1 * psf.core_px:
        return None
    return psf


class _ProfileCache:
    """
    Pixel shares of unit-flux Gaussians of any width at fixed star positions, each width computed once.

    The shape fit's finite differences move one value at a time: a share leaves every width
    as it was, a width ratio the narrower Gaussians.
    """

    def __init__(self, col0, row0, x, y, size: int):
        self.edges_col = np.asarray(col0, float)[:, None] + np.arange(size) - 0.5
        self.edges_row = np.asarray(row0, float)[:, None] + np.arange(size) - 0.5
        self.x, self.y = np.asarray(x, float)[:, None], np.asarray(y, float)[:, None]
        self.known: dict[float, np.ndarray] = {}

    def __call__(self, sigma: float) -> np.ndarray:
        """(n, size, size) pixel shares of the Gaussian of 1-sigma `sigma` [px]."""
        if sigma not in self.known:
            if len(self.known) > 64:
                self.known.clear()
            px, _ = pixel_integrated_profile(self.edges_col, self.x, sigma)
            py, _ = pixel_integrated_profile(self.edges_row, self.y, sigma)
            self.known[sigma] = py[:, :, None] * px[:, None, :]
        return self.known[sigma]
