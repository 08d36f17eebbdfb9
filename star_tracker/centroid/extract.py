"""Spot extraction: background, detection, sub-pixel centroids with covariance.

Input: a 2-D image in ADU (uint8/uint16/float). Output: `Spots` in pixel coordinates with
(0, 0) at the centre of the top-left pixel, sorted by flux (brightest first).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import erf

FLAG_SATURATED = 1 << 0
FLAG_EDGE = 1 << 1
CENTROID_METHODS = ("cog", "gaussian")


@dataclass(frozen=True)
class Spots:
    """Detected spots as parallel arrays (N entries, brightest first).

    x, y: centroid [px]; flux: background-subtracted sum [ADU]; snr: flux / its 1-sigma [-];
    cov: (N, 2, 2) centroid covariance [px^2] from the noise model; flags: bit set
    (FLAG_SATURATED, FLAG_EDGE); area: pixels above threshold; peak: max residual [ADU].
    width, height: image size [px]; background_adu, noise_adu: frame background level and
    1-sigma pixel noise [ADU]; rejected_shape: detections dropped as hot pixels or cosmic
    rays (too sharp or too thin for the PSF).
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    snr: np.ndarray
    cov: np.ndarray
    flags: np.ndarray
    area: np.ndarray
    peak: np.ndarray
    width: int
    height: int
    background_adu: float = 0.0
    noise_adu: float = 0.0
    rejected_shape: int = 0

    def __len__(self) -> int:
        return int(self.x.size)

    @staticmethod
    def empty(width: int, height: int) -> "Spots":
        z = np.zeros(0)
        return Spots(z, z, z, z, np.zeros((0, 2, 2)), np.zeros(0, np.uint32), np.zeros(0, np.int32),
                     z, width, height)

    def take(self, index: np.ndarray) -> "Spots":
        return Spots(self.x[index], self.y[index], self.flux[index], self.snr[index], self.cov[index],
                     self.flags[index], self.area[index], self.peak[index], self.width, self.height,
                     self.background_adu, self.noise_adu, self.rejected_shape)


@dataclass(frozen=True)
class CentroidConfig:
    """detection_sigma: threshold in units of the pixel noise of the PSF-matched image;
    min_area/max_area: accepted component sizes [px]; min_snr: reported spots' SNR floor;
    background_block_px: background mesh size [px]; gain_e_per_adu: for the shot-noise term
    of the covariance; saturation_adu: a spot with a pixel at or above it is flagged
    (0 = the image dtype's maximum); max_spots: keep at most this many (brightest).
    Shape test (hot pixels, cosmic rays), only when psf_sigma_px > 0: a spot is rejected when
    its brightest pixel holds more than max_peak_fraction of its flux (a Gaussian of sigma
    1 px puts at most ~16 % in one pixel), or, for spots with SNR >= shape_min_snr, when its
    narrowest second moment is below min_width_fraction * psf_sigma_px^2 (a PSF-blurred star
    is never thinner than the PSF; a cosmic-ray track is).
    method: "gaussian" (default) = weighted least-squares fit of the pixel-integrated
    Gaussian PSF (sigma = psf_sigma_px) to a 9x9 window, with the covariance of the fit;
    spots elongated beyond the PSF (streaks) and saturated spots keep the centre of gravity;
    "cog" = centre of gravity over the grown detection footprint for every spot."""

    detection_sigma: float = 5.0
    min_area: int = 2
    max_area: int = 5000
    min_snr: float = 5.0
    background_block_px: int = 32
    gain_e_per_adu: float = 1.0
    saturation_adu: float = 0.0
    max_spots: int = 500
    method: str = "gaussian"
    psf_sigma_px: float = 1.0
    max_peak_fraction: float = 0.5
    min_width_fraction: float = 0.6
    shape_min_snr: float = 10.0

    def __post_init__(self) -> None:
        bad = []
        if not (np.isfinite(self.detection_sigma) and self.detection_sigma > 0):
            bad.append(f"detection_sigma={self.detection_sigma} must be > 0")
        if not (1 <= self.min_area <= self.max_area):
            bad.append(f"need 1 <= min_area ({self.min_area}) <= max_area ({self.max_area})")
        if not (np.isfinite(self.min_snr) and self.min_snr >= 0):
            bad.append(f"min_snr={self.min_snr} must be >= 0")
        if not (4 <= self.background_block_px <= 1024):
            bad.append(f"background_block_px={self.background_block_px} must be in [4, 1024]")
        if not (np.isfinite(self.gain_e_per_adu) and self.gain_e_per_adu > 0):
            bad.append(f"gain_e_per_adu={self.gain_e_per_adu} must be > 0")
        if not (self.max_spots >= 1):
            bad.append(f"max_spots={self.max_spots} must be >= 1")
        if not (0 <= self.psf_sigma_px <= 50):
            bad.append(f"psf_sigma_px={self.psf_sigma_px} must be in [0, 50] (0 disables the shape test)")
        if self.method not in CENTROID_METHODS:
            bad.append(f"method={self.method!r} must be one of {CENTROID_METHODS}")
        if self.method == "gaussian" and self.psf_sigma_px <= 0:
            bad.append("method 'gaussian' needs psf_sigma_px > 0")
        if not (0 < self.max_peak_fraction <= 1 and 0 <= self.min_width_fraction <= 1 and self.shape_min_snr >= 0):
            bad.append("need 0 < max_peak_fraction <= 1, 0 <= min_width_fraction <= 1, shape_min_snr >= 0")
        if bad:
            raise ValueError("invalid centroid config: " + "; ".join(bad))


def estimate_background(image: np.ndarray, block: int) -> np.ndarray:
    """Smooth background [ADU]: median of each block (on every 4th pixel of every 4th row:
    64 samples per 32 px block), bilinearly interpolated back to full size. Robust to stars;
    follows stray-light gradients."""
    h, w = image.shape
    step = 4 if block >= 16 else 1
    sub = image[::step, ::step]
    b = max(2, block // step)
    ph, pw = -sub.shape[0] % b, -sub.shape[1] % b
    if ph or pw:
        sub = np.pad(sub, ((0, ph), (0, pw)), mode="reflect" if min(sub.shape) > 1 else "edge")
    tiles = sub.reshape(sub.shape[0] // b, b, sub.shape[1] // b, b).swapaxes(1, 2)
    medians = np.median(tiles.reshape(tiles.shape[0], tiles.shape[1], -1), axis=2).astype(np.float32)
    full = cv2.resize(medians, (medians.shape[1] * block, medians.shape[0] * block), interpolation=cv2.INTER_LINEAR)
    return full[:h, :w]


def robust_sigma(values: np.ndarray) -> float:
    """1.4826 x median absolute deviation: the Gaussian sigma, ignoring outliers (stars)."""
    values = values.ravel()
    med = np.median(values)
    return float(1.4826 * np.median(np.abs(values - med)))


def extract_spots(image: np.ndarray, config: CentroidConfig = CentroidConfig()) -> Spots:
    """Detect spots and compute intensity-weighted centres of gravity with covariance."""
    if image.ndim != 2 or image.size == 0:
        raise ValueError(f"expected a non-empty 2-D image, got shape {image.shape}")
    height, width = image.shape
    saturation = config.saturation_adu or (np.iinfo(image.dtype).max if image.dtype.kind in "ui" else np.inf)
    data = image.astype(np.float32)
    background = estimate_background(data, config.background_block_px)
    residual = data - background
    noise = robust_sigma(residual[::5, ::5])
    if not np.isfinite(noise) or noise <= 0:
        noise = max(float(np.std(residual)), 1e-3)  # flat or quantized image: fall back
    # Detect on the PSF-matched (3x3 Gaussian) image: better sensitivity than raw pixels.
    smoothed = cv2.GaussianBlur(residual, (5, 5), 1.0)
    smooth_noise = robust_sigma(smoothed[::5, ::5]) or noise
    mask = (smoothed > config.detection_sigma * smooth_noise).astype(np.uint8)
    # Measure each spot over its detection footprint grown by one pixel (captures the wings):
    # label the grown mask directly; footprints closer than 2 px merge into one spot.
    grown = cv2.dilate(mask, np.ones((3, 3), np.uint8))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(grown, connectivity=8)
    if count <= 1:
        return Spots.empty(width, height)
    idx = np.flatnonzero(labels)
    lab = labels.ravel()[idx]
    area = np.bincount(lab[mask.ravel()[idx] > 0], minlength=count)  # pixels above threshold
    w = residual.ravel()[idx].astype(np.float64)
    xs = (idx % width).astype(np.float64)
    ys = (idx // width).astype(np.float64)
    n = count
    flux = np.bincount(lab, w, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        cx = np.bincount(lab, w * xs, n) / flux
        cy = np.bincount(lab, w * ys, n) / flux
        # Noise-model variance of each pixel [ADU^2]: shot noise of the signal + pixel noise.
        var_pix = np.maximum(w, 0.0) / config.gain_e_per_adu + noise * noise
        dx = xs - cx[lab]
        dy = ys - cy[lab]
        f2 = flux * flux
        cov_xx = np.bincount(lab, var_pix * dx * dx, n) / f2
        cov_yy = np.bincount(lab, var_pix * dy * dy, n) / f2
        cov_xy = np.bincount(lab, var_pix * dx * dy, n) / f2
        snr = flux / np.sqrt(np.bincount(lab, var_pix, n))
    peak_value = np.full(n, -np.inf)
    np.maximum.at(peak_value, lab, data.ravel()[idx])
    peak = np.full(n, -np.inf)
    np.maximum.at(peak, lab, w)

    keep = np.zeros(n, bool)
    keep[1:] = ((area[1:] >= config.min_area) & (area[1:] <= config.max_area) & (flux[1:] > 0)
                & np.isfinite(cx[1:]) & np.isfinite(cy[1:]) & (snr[1:] >= config.min_snr))
    rejected = 0
    # Shape: intensity moments of the positive signal (minor/major = narrowest/widest width).
    positive = np.maximum(w, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        total = np.bincount(lab, positive, n)
        mxx = np.bincount(lab, positive * dx * dx, n) / total
        myy = np.bincount(lab, positive * dy * dy, n) / total
        mxy = np.bincount(lab, positive * dx * dy, n) / total
        spread = np.sqrt(0.25 * (mxx - myy) ** 2 + mxy ** 2)
        minor = 0.5 * (mxx + myy) - spread
        major = 0.5 * (mxx + myy) + spread
        sharp = peak / flux
    if config.psf_sigma_px > 0:
        # Sharpness is robust at any SNR; the width needs a well-measured spot.
        defect = keep & ((sharp > config.max_peak_fraction)
                         | ((snr >= config.shape_min_snr) & (minor < config.min_width_fraction * config.psf_sigma_px ** 2)))
        rejected = int(defect.sum())
        keep &= ~defect
    sel = np.flatnonzero(keep)
    sel = sel[np.argsort(-flux[sel], kind="stable")][: config.max_spots]
    flags = np.zeros(sel.size, np.uint32)
    flags[peak_value[sel] >= saturation] |= FLAG_SATURATED
    x0, y0 = stats[sel, cv2.CC_STAT_LEFT], stats[sel, cv2.CC_STAT_TOP]
    x1, y1 = x0 + stats[sel, cv2.CC_STAT_WIDTH], y0 + stats[sel, cv2.CC_STAT_HEIGHT]
    flags[(x0 <= 0) | (y0 <= 0) | (x1 >= width) | (y1 >= height)] |= FLAG_EDGE
    cov = np.empty((sel.size, 2, 2))
    cov[:, 0, 0] = cov_xx[sel]
    cov[:, 1, 1] = cov_yy[sel]
    cov[:, 0, 1] = cov[:, 1, 0] = cov_xy[sel]
    x_out, y_out, flux_out = cx[sel].copy(), cy[sel].copy(), flux[sel].copy()
    if config.method == "gaussian" and sel.size:
        # Point-like spots only: a streak is wider than the PSF along its length.
        point = (major[sel] < 2.5 * (config.psf_sigma_px ** 2 + 1.0 / 12.0)) & (flags & FLAG_SATURATED == 0)
        fit = fit_gaussian_psf(residual, x_out[point], y_out[point], flux_out[point], config.psf_sigma_px,
                               noise, config.gain_e_per_adu)
        good = fit[4]
        idx_point = np.flatnonzero(point)[good]
        x_out[idx_point], y_out[idx_point], flux_out[idx_point] = fit[0][good], fit[1][good], fit[2][good]
        cov[idx_point] = fit[3][good]
    return Spots(x=x_out, y=y_out, flux=flux_out, snr=snr[sel], cov=cov, flags=flags,
                 area=area[sel].astype(np.int32), peak=peak[sel], width=width, height=height,
                 background_adu=float(np.median(background[::16, ::16])), noise_adu=noise, rejected_shape=rejected)


def fit_gaussian_psf(residual: np.ndarray, x0: np.ndarray, y0: np.ndarray, flux0: np.ndarray, sigma: float,
                     noise: float, gain: float, half: int = 4, iterations: int = 8):
    """Weighted least-squares fit of a pixel-integrated Gaussian (fixed sigma [px]) to
    (2 half + 1)^2 windows of the background-subtracted image [ADU], all spots at once.

    Model: mu_ij = F P_x(j; x) P_y(i; y), P = PSF integral over the pixel (erf differences);
    weights 1 / (mu / gain + noise^2). Gauss-Newton on (x, y, F); the covariance of (x, y)
    is the inverse normal matrix's block (the Cramer-Rao bound at the solution).
    Returns x, y [px], flux [ADU], cov (N, 2, 2) [px^2], converged (N,) bool."""
    n = x0.size
    if n == 0:
        return x0, y0, flux0, np.zeros((0, 2, 2)), np.zeros(0, bool)
    height, width = residual.shape
    offsets = np.arange(-half, half + 1)
    cols = np.rint(x0).astype(np.int64)[:, None] + offsets[None, :]
    rows = np.rint(y0).astype(np.int64)[:, None] + offsets[None, :]
    inside = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    data = residual[np.clip(rows, 0, height - 1)[:, :, None], np.clip(cols, 0, width - 1)[:, None, :]].astype(float)
    x, y, flux = x0.astype(float).copy(), y0.astype(float).copy(), flux0.astype(float).copy()
    inv_s = 1.0 / sigma
    root2 = np.sqrt(2.0)

    def axis_terms(edges_lo, centre):
        a = (edges_lo - centre[:, None]) * inv_s
        b = a + inv_s  # pixel width 1 px
        prob = 0.5 * (erf(b / root2) - erf(a / root2))
        # d prob / d centre = (phi(a) - phi(b)) / sigma
        deriv = (np.exp(-0.5 * a * a) - np.exp(-0.5 * b * b)) * (inv_s / np.sqrt(2 * np.pi))
        return prob, deriv

    def damping(normal):  # relative 1e-12 on the diagonal (plus an absolute floor)
        return (1e-12 * np.abs(np.diagonal(normal, axis1=1, axis2=2)) + 1e-300)[:, :, None] * np.eye(3)[None]

    normal = np.zeros((n, 3, 3))
    for _ in range(iterations):
        px, dpx = axis_terms(cols - 0.5, x)
        py, dpy = axis_terms(rows - 0.5, y)
        shape = py[:, :, None] * px[:, None, :]
        model = flux[:, None, None] * shape
        weight = np.where(inside, 1.0 / (np.maximum(model, 0.0) / gain + noise * noise), 0.0)
        jac = np.stack([flux[:, None, None] * py[:, :, None] * dpx[:, None, :],
                        flux[:, None, None] * dpy[:, :, None] * px[:, None, :], shape], axis=-1)  # (n, S, S, 3)
        jw = jac * weight[..., None]
        normal = np.einsum("nijk,nijl->nkl", jw, jac)
        gradient = np.einsum("nijk,nij->nk", jw, data - model)
        # A whisper of Levenberg-Marquardt damping keeps every spot's system solvable, so one
        # degenerate spot (e.g. flux ~ 0) cannot fail the batch; it is flagged below instead.
        step = np.linalg.solve(normal + damping(normal), gradient[..., None])[..., 0]
        step[:, :2] = np.clip(step[:, :2], -1.0, 1.0)  # trust region: at most 1 px per iteration
        x, y, flux = x + step[:, 0], y + step[:, 1], np.maximum(flux + step[:, 2], 1e-9)
        if np.all(np.abs(step[:, :2]) < 1e-5):
            break
    cov = np.linalg.inv(normal + damping(normal))[:, :2, :2]
    converged = (np.all(np.isfinite(cov.reshape(n, -1)), axis=1) & (cov[:, 0, 0] > 0) & (cov[:, 1, 1] > 0)
                 & (np.abs(x - x0) < half - 1) & (np.abs(y - y0) < half - 1) & np.isfinite(x) & np.isfinite(y))
    return x, y, flux, cov, converged
