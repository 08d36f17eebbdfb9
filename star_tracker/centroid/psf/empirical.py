# SPDX-License-Identifier: Apache-2.0
"""
Empirical PSF: the frame's own star profile, measured from its bright stars, as the fit model.

Where the Gaussian does not describe the stars (a defocused ring, broad wings), their centre
of gravity was the fallback: unbiased, but noisy (every pixel weighs alike, far from the
Cramer-Rao bound). Here the bright stars' pixels, each normalised to its star's flux, are
binned by their (elliptical) radius from the star: the profile P(r) of the pixel-integrated
PSF. A square pixel's integral is isotropic to second order, so a round PSF's pixel values
depend on the radius alone to that order; the shape (axis ratio and angle) comes from the
stacked pixels' second moments. Radial bins pool every star's pixels (thousands of samples
for ~40 bins: a smooth profile without blurring it). Each star is then fitted with F P(r)
(x, y, flux; weighted least squares, the inverse Fisher information as covariance); the
build is repeated once from the fitted positions. The model is point-symmetric: positions
are the centre of symmetry, which for a symmetric PSF is its light centroid.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..windows import PsfStart, PsfWindows

BIN_PX = 0.1  # radial bin [px]
SMOOTHING_PX = 0.3  # the profile's running mean over this radius span [px]: the bins are far finer than the pixels
MIN_TEMPLATE_STARS = 5  # fewer bright stars give too noisy a profile
MIN_BIN_SAMPLES = 3  # a bin with fewer samples takes its neighbours' value
CLIP_MADS = 4.0  # a radial bin's samples farther than this many robust sigmas from its median are left out
BUILD_PASSES = 2  # profile from the first positions, stars refitted, profile again
STEP_DONE_PX = 1e-3  # a fit whose position step is below this [px] is done (Gauss-Newton: the next is far smaller)


@dataclass(frozen=True)
class EmpiricalPsf:
    """
    Pixel-integrated PSF as a profile of the elliptical radius.

    profile[k]: share of a star's flux in a pixel whose centre lies at radius (k + 0.5) BIN_PX
    [px] (0 beyond the last bin); slope: its derivative [1/px]. Radius r = sqrt(u^2 stretch_u
    + v^2 stretch_v), (u, v) the offset rotated by -angle [rad]; stretch_u * stretch_v = 1.
    """

    profile: np.ndarray
    slope: np.ndarray
    angle: float = 0.0
    stretch_u: float = 1.0
    stretch_v: float = 1.0

    def sample(self, dx: np.ndarray, dy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Value and its gradients along dx, dy at offsets dx, dy [px] from the star (any shape)."""
        c, s = np.cos(self.angle), np.sin(self.angle)
        u, v = dx * c + dy * s, -dx * s + dy * c
        r = np.sqrt(self.stretch_u * u * u + self.stretch_v * v * v)
        centres = (np.arange(self.profile.size) + 0.5) * BIN_PX
        outer = self.profile.size * BIN_PX
        value = np.interp(r, centres, self.profile, right=0.0)
        slope = np.where(r < outer, np.interp(r, centres, self.slope, right=0.0), 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            du = np.where(r > 1e-9, self.stretch_u * u / r, 0.0)
            dv = np.where(r > 1e-9, self.stretch_v * v / r, 0.0)
        return value, slope * (du * c - dv * s), slope * (du * s + dv * c)


def _offsets(col0, row0, size: int, x, y) -> tuple[np.ndarray, np.ndarray]:
    """(n, S, S) offsets [px] of each window pixel's centre from its star."""
    steps = np.arange(size)
    dx = (np.asarray(col0, float)[:, None] + steps)[:, None, :] - np.asarray(x, float)[:, None, None]
    dy = (np.asarray(row0, float)[:, None] + steps)[:, :, None] - np.asarray(y, float)[:, None, None]
    n = dx.shape[0]
    return np.broadcast_to(dx, (n, size, size)), np.broadcast_to(dy, (n, size, size))


def _shape(dx, dy, share) -> tuple[float, float, float]:
    """Angle [rad] and stretches of the stacked unit-flux pixels' second moments (within their footprint)."""
    w = np.clip(share, 0.0, None)
    total = w.sum()
    if total <= 0:
        return 0.0, 1.0, 1.0
    mxx, myy, mxy = (w * dx * dx).sum() / total, (w * dy * dy).sum() / total, (w * dx * dy).sum() / total
    angle = 0.5 * np.arctan2(2.0 * mxy, mxx - myy)
    spread = np.sqrt(((mxx - myy) / 2.0) ** 2 + mxy ** 2)
    major, minor = (mxx + myy) / 2.0 + spread, (mxx + myy) / 2.0 - spread
    if not (minor > 0 and major > 0):
        return 0.0, 1.0, 1.0
    ratio = np.sqrt(major / minor)  # axis ratio; the radius is measured in units that make it round
    return float(angle), float(1.0 / ratio), float(ratio)


def _template(win, valid, col0, row0, x, y, smoothing_px: float, round_: bool) -> EmpiricalPsf | None:
    """
    One build: the stars' unit-flux pixels binned by elliptical radius, a running mean over smoothing_px [px].

    round_: the radius is the plain one (no shape measured).
    """
    size = win.shape[1]
    flux = np.where(valid, win, 0.0).sum(axis=(1, 2))
    ok = flux > 0
    if ok.sum() < MIN_TEMPLATE_STARS:
        return None
    dx, dy = _offsets(col0[ok], row0[ok], size, x[ok], y[ok])
    use = valid[ok]
    share = win[ok] / flux[ok][:, None, None]
    angle, stretch_u, stretch_v = (0.0, 1.0, 1.0) if round_ else _shape(dx[use], dy[use], share[use])
    shape = EmpiricalPsf(np.zeros(1), np.zeros(1), angle, stretch_u, stretch_v)
    c, s = np.cos(angle), np.sin(angle)
    u, v = dx[use] * c + dy[use] * s, -dx[use] * s + dy[use] * c
    radius = np.sqrt(shape.stretch_u * u * u + shape.stretch_v * v * v)
    outer = 0.5 * (size - 1)  # the window's inscribed radius: every direction sampled
    keep = radius < outer
    bins = (radius[keep] / BIN_PX).astype(np.int64)
    count = np.bincount(bins, minlength=int(outer / BIN_PX))
    profile = np.full(count.size, np.nan)
    filled = count >= MIN_BIN_SAMPLES
    if filled.sum() < 3:
        return None
    # Per bin the mean of the samples within CLIP_MADS robust sigmas of their median: a cosmic
    # ray or a neighbour in one star's window is a few samples of many, not the profile.
    order = np.argsort(bins, kind="stable")
    values = share[use][keep][order]
    starts = np.concatenate([[0], np.cumsum(count)])
    for k in np.flatnonzero(filled):
        v = values[starts[k]:starts[k + 1]]
        centre = np.median(v)
        spread = 1.4826 * np.median(np.abs(v - centre))
        inside = np.abs(v - centre) <= CLIP_MADS * spread if spread > 0 else np.ones(v.size, bool)
        profile[k] = v[inside].mean()
    centres = (np.arange(count.size) + 0.5) * BIN_PX
    profile = np.interp(centres, centres[filled], profile[filled])
    half = max(int(round(0.5 * smoothing_px / BIN_PX - 0.5)), 0)  # bins each side: 0.3 px -> 3 bins
    profile = np.convolve(np.pad(profile, half, mode="edge"), np.ones(2 * half + 1) / (2 * half + 1), mode="valid")
    psf = EmpiricalPsf(profile, np.gradient(profile, BIN_PX), angle, stretch_u, stretch_v)
    # Unit flux: a star's window of pixels sums to 1 under the model (on average over the stars).
    p, _, _ = psf.sample(dx, dy)
    norm = float(np.median(np.where(use, p, 0.0).sum(axis=(1, 2))))
    if not np.isfinite(norm) or norm <= 0:
        return None
    return EmpiricalPsf(profile / norm, psf.slope / norm, angle, stretch_u, stretch_v)


def fit_empirical(psf, windows: PsfWindows, start: PsfStart, noise: float, gain: float, iterations: int = 8):
    """
    Fit a PSF model to n windows: (x, y, flux, cov (n, 2, 2), flux_var, converged).

    `psf`: any model with sample(dx, dy) -> (value, d/ddx, d/ddy) of unit flux (EmpiricalPsf,
    elliptical.EllipticalGaussianPsf). windows: background-subtracted data [ADU] with their
    valid masks, top-left pixel (col0, row0); start: x, y [px], flux [ADU] (n,). Model
    F * psf(pixel - (x, y)); weights 1 /
    (model / gain + noise^2); Gauss-Newton with steps clipped to 0.5 px, a window done once
    its step is below STEP_DONE_PX (the covariance is at its last position); converged when
    finite, within 2 px of the start, flux > 0.
    """
    win, valid, col0, row0 = windows
    x0, y0, flux0 = start
    size = win.shape[1]
    x, y = np.asarray(x0, float).copy(), np.asarray(y0, float).copy()
    flux = np.maximum(np.asarray(flux0, float).copy(), 1e-9)
    n = x.size
    data = np.where(valid, win, 0.0)
    info = np.zeros((n, 3, 3))
    active = np.arange(n)
    for _ in range(iterations):
        if active.size == 0:
            break
        a = active
        dx, dy = _offsets(col0[a], row0[a], size, x[a], y[a])
        p, px, py = psf.sample(dx, dy)
        f = flux[a][:, None, None]
        model = f * p
        weight = np.where(valid[a], 1.0 / (np.maximum(model, 0.0) / gain + noise ** 2), 0.0).reshape(a.size, -1)
        jac = np.stack([-f * px, -f * py, p], axis=-1).reshape(a.size, -1, 3)
        residual = (data[a] - model).reshape(a.size, -1)
        info[a] = np.einsum("npi,np,npj->nij", jac, weight, jac)
        grad = np.einsum("npi,np,np->ni", jac, weight, residual)
        damped = info[a] + 1e-9 * np.trace(info[a], axis1=1, axis2=2)[:, None, None] * np.eye(3)
        ok = np.isfinite(damped).all(axis=(1, 2)) & (np.abs(np.linalg.det(damped)) > 0)
        step = np.zeros((a.size, 3))
        if ok.any():
            step[ok] = np.linalg.solve(damped[ok], grad[ok][..., None])[..., 0]
        step = np.nan_to_num(step)
        shift = np.hypot(step[:, 0], step[:, 1])
        scale = np.where(shift > 0.5, 0.5 / np.maximum(shift, 1e-12), 1.0)
        x[a] += step[:, 0] * scale
        y[a] += step[:, 1] * scale
        flux[a] = np.maximum(flux[a] + step[:, 2], 1e-9)
        active = a[shift >= STEP_DONE_PX]
    inverse = np.full((n, 3, 3), np.nan)
    ok = np.isfinite(info).all(axis=(1, 2)) & (np.abs(np.linalg.det(info)) > 0)
    if ok.any():
        inverse[ok] = np.linalg.inv(info[ok])
    cov, flux_var = inverse[:, :2, :2], inverse[:, 2, 2]
    moved = np.hypot(x - np.asarray(x0, float), y - np.asarray(y0, float))
    with np.errstate(invalid="ignore"):
        converged = (np.isfinite(x) & np.isfinite(y) & (moved < 2.0) & (flux > 1e-6) & (flux_var > 0)
                     & np.isfinite(cov).all(axis=(1, 2)) & (cov[:, 0, 0] > 0) & (cov[:, 1, 1] > 0))
    return x, y, flux, cov, flux_var, converged


def build_empirical_psf(windows: PsfWindows, x, y, noise: float, gain: float, smoothing_px: float = SMOOTHING_PX,
                        round_: bool = False) -> EmpiricalPsf | None:
    """
    Return the profile built from bright stars' windows (see the module docstring); None with too few stars.

    windows: background-subtracted data [ADU], valid masks, top-left pixels (PsfWindows).
    Positions x, y [px] start the build (a Gaussian fit's: unbiased for a symmetric PSF);
    each further pass refits them with the last profile. smoothing_px: the profile's running
    mean [px] (wider for faint stars: less noise, softer edges); round_: a round profile (the
    stacked moments of faint stars are noise: they read 1.03-1.13:1 on round rings of SNR 11).
    """
    win, valid, col0, row0 = windows
    x, y = np.asarray(x, float), np.asarray(y, float)
    psf = _template(win, valid, col0, row0, x, y, smoothing_px, round_)
    for _ in range(BUILD_PASSES - 1):
        if psf is None:
            return None
        flux0 = np.where(valid, win, 0.0).sum(axis=(1, 2))
        fx, fy, _, _, _, ok = fit_empirical(psf, windows, PsfStart(x, y, flux0), noise, gain)
        if ok.sum() < MIN_TEMPLATE_STARS:
            return psf
        x, y = np.where(ok, fx, x), np.where(ok, fy, y)
        psf = _template(win[ok], valid[ok], col0[ok], row0[ok], x[ok], y[ok], smoothing_px, round_) or psf
    return psf
