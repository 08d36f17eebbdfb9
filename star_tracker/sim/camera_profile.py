# SPDX-License-Identifier: Apache-2.0
"""
Fit a camera profile (the SensorModel parameters of sim/sensor.py) to real frames of known attitude.

PSF width and shape, conversion gain and read noise from the image statistics, background level
and vignetting, hot pixels, and the photometric zero point against the Hipparcos Hp magnitudes
of the identified stars, each with a 1-sigma uncertainty.

Methods and their assumptions (the comparison: docs/BENCHMARKS.md, "The simulator against a real camera"):

- Background and noise: every image is cut into tiles; in each tile the pixels away from
  detected spots and catalog stars are modelled as a Gaussian N(mu, s^2) that the camera
  rounded to integers and clipped at 0 (the black level is subtracted before an 8-bit output,
  so half of the sky reads 0): a censored maximum-likelihood fit gives mu and s even where
  most pixels are 0. The per-tile mu across all frames is fitted with
  b + c r^2/r_c^2 + g_x dx + g_y dy (level at the centre, a radial term, the renderer's
  stray-light gradient; r_c = half the image diagonal); the frames' pointings differ, so the
  sky's own structure averages out.
- Stars: on every identified, isolated, unsaturated star a pixel-integrated Gaussian (the
  renderer's PSF) seen through the clip at 0 is fitted (flux, width, position, background).
- Gain (photon transfer on stars): the residual variance of the star pixels, each squared
  residual divided by (1 - its leverage) since the fit absorbs part of the noise of its
  brightest pixels, grows with the model signal S [ADU] as var = s_bg^2 + S/g + (k S)^2
  (shot noise of the star plus a relative model/response error k); the linear term is 1/g.
  When it is below 2 sigma the gain is reported as the 2-sigma lower limit. Only frames of
  one exposure and gain setting may be mixed.
- Read noise: s_bg^2 = (sigma_r/g)^2 + mu/g + 1/12, i.e. the background above the clip level is
  signal that carries shot noise and the output's zero is the true zero (bias 0).
- Zero point and vignetting: the Gaussian flux per second [ADU/s] against Hp and the radius:
  log10(F) + 0.4 Hp = log10(zp) + log10(1 - a r^2/r_c^2) (slope fixed; the renderer's
  vignetting, from the stars since a sky near 0 ADU shows none; robust loss); the free
  slope and a colour term are reported as checks. In ADU, so independent of the gain.
- PSF and photometry use the stars with a Gaussian-fit SNR >= MIN_SNR: on fainter ones the
  noise of the peak pixel narrows the fit (a 0.8 px PSF at SNR 7 fits ~0.65 px).
- Hot pixels: pixels above mu + 8 s in at least 60 % of the frames (the stars move between
  frames, a hot pixel does not).

Units: ADU, electrons [e-], pixels, seconds; frames: the camera's sensor frame
(star_tracker_optical: +X right, +Y down, +Z boresight), rotations sensor -> ICRS.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares, minimize
from scipy.special import erf, ndtr

from ..centroid import CentroidConfig, extract_spots
from ..models.camera import CameraModel
from ..models.catalog import StarCatalog
from .sensor import SensorModel

STAMP_HALF_PX = 6  # star stamps are (2*6 + 1)^2 px: > 4 sigma of the PSFs seen here
HOT_PIXEL_SIGMA = 8.0
ROUNDING_VAR = 1.0 / 12.0  # [ADU^2]: the variance that rounding to integers adds
MIN_SNR = 15.0  # Gaussian flux / (s_bg sqrt(4 pi) sigma): below it the fitted width is biased low
HOT_PIXEL_FRACTION_OF_FRAMES = 0.6


@dataclass(frozen=True)
class Measured:
    """A fitted value and its 1-sigma uncertainty (same unit)."""

    value: float
    sigma: float

    def __format__(self, spec: str) -> str:
        return f"{format(self.value, spec)} ± {format(self.sigma, spec)}"


@dataclass(frozen=True)
class ProfileFrame:
    """
    One real (or rendered) frame to fit.

    Image (H, W) [ADU] as the camera wrote it, camera (its geometry), rotation (3, 3) sensor
    -> ICRS at mid-exposure, exposure_s [s].
    """

    image: np.ndarray
    camera: CameraModel
    rotation: np.ndarray
    exposure_s: float


@dataclass(frozen=True)
class StarFits:
    """
    Per identified star (parallel arrays).

    Frame index, hip, hp, b_v [mag]; x, y [px]; flux [ADU] and psf_sigma_px [px] of the
    Gaussian fit; local background [ADU]; aperture_flux [ADU]: the fit's flux plus the
    data-minus-fit residual within 5 sigma (equal to flux for a Gaussian PSF, larger when the
    PSF has wings).
    """

    frame: np.ndarray
    hip: np.ndarray
    hp: np.ndarray
    b_v: np.ndarray
    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    psf_sigma_px: np.ndarray
    background: np.ndarray
    aperture_flux: np.ndarray


@dataclass(frozen=True)
class CameraProfile:
    """
    The fitted camera (values with 1-sigma uncertainties) and the evidence behind it.

    inverse_gain_adu_per_e: the photon-transfer slope 1/g [ADU/e-] (may be consistent with 0);
    gain_e_per_adu [e-/ADU]: 1/slope, or, when the slope is below 2 sigma
    (gain_is_lower_limit), the 2-sigma lower limit 1/(slope + 2 sigma) (the largest shot noise
    the data allow; its sigma is NaN); read_noise_e [e-] at that gain; psf_sigma_px [px];
    background_adu: level at the image centre [ADU]; background_noise_adu: pixel noise of the
    background [ADU]; vignetting_at_corner [-]; gradient_adu_per_px: (x, y) [ADU/px];
    log10_zero_point_adu_per_s: log10 of ADU/s from an Hp = 0 star at the image centre;
    zero_point_free_slope: d log10(flux)/d Hp fitted freely (-0.4 for a linear camera);
    color_coefficient: c of Hp + c (B-V); hot_pixel_fraction [-] and hot_pixel_level_adu
    [ADU] above the background; psf_wing_excess:
    aperture flux (5 sigma) / Gaussian flux - 1 [-] (0 for a Gaussian PSF);
    exposure_s, width, height: of the frames; stars: every star's fit, used: those with
    SNR >= MIN_SNR that the PSF and photometry come from; ptc: binned
    (signal [ADU], variance [ADU^2], count) of the star photon transfer and ptc_model_error
    its fitted k^2 [-]; tiles: the background tiles of every frame (tile_statistics rows).
    """

    gain_e_per_adu: Measured
    inverse_gain_adu_per_e: Measured
    gain_is_lower_limit: bool
    read_noise_e: Measured
    psf_sigma_px: Measured
    background_adu: Measured
    background_noise_adu: Measured
    vignetting_at_corner: Measured
    gradient_adu_per_px: tuple[float, float]
    log10_zero_point_adu_per_s: Measured
    zero_point_free_slope: Measured
    color_coefficient: Measured
    hot_pixel_fraction: float
    hot_pixel_level_adu: float
    psf_wing_excess: Measured
    exposure_s: float
    width: int
    height: int
    n_frames: int
    stars: StarFits = field(repr=False)
    used: np.ndarray = field(repr=False)
    ptc: np.ndarray = field(repr=False)
    tiles: np.ndarray = field(repr=False)
    ptc_model_error: float = field(default=0.0, repr=False)

    def sensor_model(self, base: SensorModel = SensorModel()) -> SensorModel:
        """
        Return `base` with the fitted values.

        The background goes to the sky term (vignetted), dark current, DSNU, PRNU and cosmic
        rays off (not measurable from these frames), hot pixels as a dark-current multiple
        of a small dark floor, bias 0, 8-bit output.
        """
        g = self.gain_e_per_adu.value
        t = self.exposure_s
        dark_floor = 1e-3 * max(self.background_adu.value, 1e-3) * g / t  # carries the hot pixels only
        area = np.pi * (0.5 * base.aperture_diameter_m) ** 2
        zero_point_e_per_s = 10 ** self.log10_zero_point_adu_per_s.value * g
        photon_flux = zero_point_e_per_s / (area * base.optical_transmission * base.quantum_efficiency)
        return replace(
            base, exposure_s=t, gain_e_per_adu=g, read_noise_e=self.read_noise_e.value,
            psf_sigma_px=self.psf_sigma_px.value, photon_flux_hp0=float(photon_flux), color_coefficient=0.0,
            background_e_per_px_s=max(self.background_adu.value * g / t - dark_floor, 0.0),
            stray_light_gradient_e_per_px2_s=(self.gradient_adu_per_px[0] * g / t, self.gradient_adu_per_px[1] * g / t),
            vignetting_at_corner=float(np.clip(self.vignetting_at_corner.value, 0.0, 0.99)),
            dark_e_per_px_s=dark_floor, dark_reference_k=base.temperature_k, dsnu_fraction=0.0, prnu_fraction=0.0,
            hot_pixel_fraction=float(min(self.hot_pixel_fraction, 0.1)),
            hot_pixel_dark_factor=float(max(self.hot_pixel_level_adu, 0.0) * g / t / dark_floor),
            cosmic_ray_rate_per_cm2_s=0.0, bias_adu=0.0, adc_bits=8, full_well_e=float(255.0 * g * 1.5))


# ------------------------------------------------------------------ background statistics
def censored_gaussian_fit(values: np.ndarray, upper: float | None = None) -> tuple[float, float, float, float]:
    """
    Return (mu, s, sigma_mu, sigma_s) [ADU] of integer pixel values from a rounded, clipped Gaussian.

    The values are a Gaussian N(mu, s^2) rounded to the nearest integer and clipped at 0:
    maximum likelihood over the histogram, 0 counted as "at or below 0.5", values above
    `upper` (default mu + 5 s of a first robust pass) as censored above (faint stars, hot
    pixels). Uncertainties from the Hessian.
    """
    values = np.asarray(values).ravel()
    if values.size < 20:
        raise ValueError(f"need at least 20 background pixels, got {values.size}")
    rounded = np.rint(values).astype(np.int64)
    median = float(np.median(rounded))
    spread = max(1.4826 * float(np.median(np.abs(rounded - median))), 0.5)
    if upper is None:
        upper = np.ceil(median + 6.0 * spread + 3.0)
    top = int(upper)
    counts = np.bincount(np.clip(rounded, 0, top + 1), minlength=top + 2).astype(float)
    k = np.arange(top + 1, dtype=float)

    def nll(p):
        mu, log_s = p
        s = np.exp(log_s)
        cdf = ndtr((np.append(k + 0.5, np.inf) - mu) / s)
        prob = np.diff(np.concatenate([[0.0], cdf]))
        prob[-1] = 1.0 - cdf[-2]  # above `top`: censored
        return -float(np.sum(counts * np.log(np.maximum(prob, 1e-300))))

    start = np.array([median, np.log(spread)])
    best = minimize(nll, start, method="Nelder-Mead", options=dict(xatol=1e-6, fatol=1e-6, maxiter=2000)).x
    hessian = _numeric_hessian(nll, best)
    try:
        cov = np.linalg.inv(hessian)
        sigma_mu, sigma_log_s = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        sigma_mu = sigma_log_s = np.inf
    s = float(np.exp(best[1]))
    return float(best[0]), s, float(sigma_mu), float(s * sigma_log_s)


def _numeric_hessian(f, x, step=1e-3):
    n = x.size
    h = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            e_i, e_j = np.eye(n)[i] * step, np.eye(n)[j] * step
            h[i, j] = (f(x + e_i + e_j) - f(x + e_i - e_j) - f(x - e_i + e_j) + f(x - e_i - e_j)) / (4 * step * step)
    return h


def star_mask(shape: tuple[int, int], x: np.ndarray, y: np.ndarray, radius_px: float) -> np.ndarray:
    """Return True where a pixel lies within radius_px of any (x, y) [px]."""
    import cv2

    mask = np.zeros(shape, np.uint8)
    for cx, cy in zip(np.asarray(x, float), np.asarray(y, float)):
        if np.isfinite(cx) and np.isfinite(cy):
            cv2.circle(mask, (int(round(cx)), int(round(cy))), int(np.ceil(radius_px)), 1, -1)
    return mask.astype(bool)


def tile_statistics(image: np.ndarray, masked: np.ndarray, tile_px: int = 64) -> np.ndarray:
    """
    Censored Gaussian fit of the unmasked pixels of every tile.

    Rows (x_centre, y_centre, mu, s, sigma_mu) [px, ADU]; tiles with fewer than half their
    pixels free are left out.
    """
    height, width = image.shape
    rows = []
    for r0 in range(0, height - tile_px // 2, tile_px):
        for c0 in range(0, width - tile_px // 2, tile_px):
            block = image[r0:r0 + tile_px, c0:c0 + tile_px]
            free = ~masked[r0:r0 + tile_px, c0:c0 + tile_px]
            if free.sum() < 0.5 * block.size:
                continue
            mu, s, sigma_mu, _ = censored_gaussian_fit(block[free])
            rows.append((c0 + 0.5 * (block.shape[1] - 1), r0 + 0.5 * (block.shape[0] - 1), mu, s, sigma_mu))
    return np.array(rows, float).reshape(-1, 5)


def fit_background(tiles: np.ndarray, width: int, height: int) -> tuple[Measured, float, tuple[float, float]]:
    """
    Fit mu = b + c r^2/r_c^2 + g_x dx + g_y dy to tile means (rows as tile_statistics, pooled over frames).

    (b at the centre [ADU], c [ADU], (g_x, g_y) [ADU/px]). Additive, because a
    black-level-subtracted sky near 0 ADU gives no vignetting ratio; the uncertainty of b
    from the least-squares covariance scaled by the residual scatter.
    """
    x, y, mu = tiles[:, 0], tiles[:, 1], tiles[:, 2]
    dx, dy = x - (width - 1) / 2, y - (height - 1) / 2
    design = np.column_stack([np.ones_like(x), radius_squared(x, y, width, height), dx, dy])
    coef, *_ = np.linalg.lstsq(design, mu, rcond=None)
    residual = mu - design @ coef
    dof = max(mu.size - design.shape[1], 1)
    cov = np.linalg.inv(design.T @ design) * float(residual @ residual) / dof
    return Measured(float(coef[0]), float(np.sqrt(cov[0, 0]))), float(coef[1]), (float(coef[2]), float(coef[3]))


def radius_squared(x, y, width: int, height: int) -> np.ndarray:
    """r^2/r_c^2 of the renderer's vignetting: 0 at the centre, 1 at the corner [-]."""
    dx, dy = np.asarray(x) - (width - 1) / 2, np.asarray(y) - (height - 1) / 2
    return (dx ** 2 + dy ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)


# ------------------------------------------------------------------ stars
def gaussian_stamp(params: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """
    Background + flux x pixel-integrated circular Gaussian, as the renderer draws a star.

    Params (x, y, flux [ADU], sigma [px], background [ADU]); cols, rows: pixel indices.
    """
    x, y, flux, sigma, background = params
    scale = 1.0 / (np.sqrt(2.0) * abs(sigma))
    px = 0.5 * (erf((cols + 0.5 - x) * scale) - erf((cols - 0.5 - x) * scale))
    py = 0.5 * (erf((rows + 0.5 - y) * scale) - erf((rows - 0.5 - y) * scale))
    return background + flux * np.outer(py, px)


def clipped_mean(model: np.ndarray, noise_adu: float) -> np.ndarray:
    """
    Return the expected value of max(X, 0), X ~ N(model, noise_adu^2) [ADU].

    What a camera that clips at 0 records on average where the expected signal is `model`
    (noise_adu 0: no clipping).
    """
    if noise_adu <= 0:
        return model
    z = model / noise_adu
    return model * ndtr(z) + noise_adu * np.exp(-0.5 * z * z) / np.sqrt(2.0 * np.pi)


def fit_star(image: np.ndarray, x: float, y: float, sigma_guess: float = 1.0, noise_adu: float = 0.0,
             half: int = STAMP_HALF_PX):
    """
    Fit the stamp around (x, y) [px] by least squares with gaussian_stamp seen through the clip at 0.

    The camera's clip: clipped_mean with the background noise noise_adu [ADU]; without it a
    background near 0 reads high and the wings, the width and the flux come out low. Returns
    (params as gaussian_stamp, the stamp [ADU], the expected recorded stamp [ADU], the leverage
    of each pixel in the fit [-]) or None at the image edge or when the fit fails.
    """
    height, width = image.shape
    c0, r0 = int(round(x)), int(round(y))
    if not (half <= c0 < width - half and half <= r0 < height - half):
        return None
    cols = np.arange(c0 - half, c0 + half + 1, dtype=float)
    rows = np.arange(r0 - half, r0 + half + 1, dtype=float)
    stamp = image[r0 - half:r0 + half + 1, c0 - half:c0 + half + 1].astype(float)
    background = float(np.median(np.concatenate([stamp[0], stamp[-1], stamp[:, 0], stamp[:, -1]])))
    flux = max(float(stamp.sum() - background * stamp.size), 1.0)
    start = np.array([x, y, flux, sigma_guess, background])
    lower = [x - 2.0, y - 2.0, 0.0, 0.3, -50.0]
    upper = [x + 2.0, y + 2.0, np.inf, 5.0, 255.0 * 4]

    def recorded(p):
        return clipped_mean(gaussian_stamp(p, cols, rows), noise_adu)

    try:
        result = least_squares(lambda p: (recorded(p) - stamp).ravel(), start, bounds=(lower, upper), x_scale="jac")
    except ValueError:
        return None
    if not result.success:
        return None
    jac = result.jac
    try:
        leverage = np.sum((jac @ np.linalg.inv(jac.T @ jac)) * jac, axis=1).reshape(stamp.shape)
    except np.linalg.LinAlgError:
        return None
    return result.x, stamp, recorded(result.x), leverage


def identified_stars(frame: ProfileFrame, catalog: StarCatalog, config: CentroidConfig,
                     match_radius_px: float = 3.0, isolation_px: float = 8.0):
    """
    Catalog stars of the frame matched to detected spots: (catalog indices, spots, spot indices).

    A star counts when one spot lies within match_radius_px of its projection, no other
    catalog star lies within isolation_px (blends) and the spot's peak is below the
    saturation level (fit_stars also drops stamps with a pixel at it).
    """
    spots = extract_spots(frame.image, config)
    camera = frame.camera
    u, v, front = camera.project(catalog.unit_vectors() @ frame.rotation)
    seen = np.flatnonzero(front & camera.in_image(u, v, margin=STAMP_HALF_PX + 1))
    if seen.size == 0 or spots.x.size == 0:
        return seen[:0], spots, seen[:0]
    d = np.hypot(spots.x[None, :] - u[seen, None], spots.y[None, :] - v[seen, None])
    nearest = d.argmin(axis=1)
    close = d[np.arange(seen.size), nearest] <= match_radius_px
    # one spot per star and one star per spot
    claims = np.bincount(nearest[close], minlength=spots.x.size)
    unique = close & (claims[nearest] == 1)
    all_u, all_v = u[front], v[front]
    neighbours = np.array([np.sum(np.hypot(all_u - u[i], all_v - v[i]) < isolation_px) - 1 for i in seen])
    saturation = config.saturation_adu or 255.0
    peak_ok = spots.peak[nearest] + spots.background_adu < saturation
    keep = unique & (neighbours == 0) & peak_ok
    return seen[keep], spots, nearest[keep]


def fit_stars(frames: list[ProfileFrame], catalog: StarCatalog, config: CentroidConfig, noise_adu: float = 0.0):
    """
    fit_star (with the background noise noise_adu [ADU]) on every identified, isolated, unsaturated star of every frame.

    (StarFits, rows (model signal above background [ADU], squared residual / (1 - leverage)
    [ADU^2]) of all star pixels: an unbiased estimate of each pixel's noise variance, since the
    fit itself absorbs part of the noise of its brightest pixels).
    """
    columns = {name: [] for name in StarFits.__dataclass_fields__}
    residuals = []
    for index, frame in enumerate(frames):
        stars, spots, spot_index = identified_stars(frame, catalog, config)
        for star, s in zip(stars, spot_index):
            fitted = fit_star(frame.image, float(spots.x[s]), float(spots.y[s]), config.psf_sigma_px or 1.0, noise_adu)
            if fitted is None:
                continue
            params, stamp, recorded, leverage = fitted
            if stamp.max() >= (config.saturation_adu or 255.0):
                continue  # a clipped top: neither width nor flux are measurable
            x, y, flux, sigma, background = params
            yy, xx = np.mgrid[0:stamp.shape[0], 0:stamp.shape[1]]
            half = stamp.shape[0] // 2
            radius = np.hypot(xx - half - (x - round(x)), yy - half - (y - round(y)))
            aperture = radius <= min(5.0 * abs(sigma), half)
            values = dict(frame=index, hip=int(catalog.hip[star]), hp=float(catalog.hp[star]),
                          b_v=float(catalog.b_v[star]), x=x, y=y, flux=flux, psf_sigma_px=abs(sigma),
                          background=background,
                          aperture_flux=float(flux + np.sum((stamp - recorded)[aperture])))
            for name, value in values.items():
                columns[name].append(value)
            signal = gaussian_stamp(np.array([x - round(x) + half, y - round(y) + half, flux, sigma, 0.0]),
                                    np.arange(stamp.shape[1], dtype=float), np.arange(stamp.shape[0], dtype=float))
            usable = leverage < 0.9
            unbiased = ((stamp - recorded) ** 2)[usable] / (1.0 - leverage[usable])
            residuals.append(np.column_stack([signal[usable], unbiased]))
    stars = StarFits(**{name: np.asarray(values) for name, values in columns.items()})
    return stars, (np.concatenate(residuals) if residuals else np.zeros((0, 2)))


def photon_transfer_from_stars(residuals: np.ndarray, background_noise_adu: float, min_signal_adu: float = 2.0,
                               bins: int = 12) -> tuple[Measured, float, np.ndarray]:
    """
    Inverse gain from star pixels.

    Residual variance in log-spaced bins of the model signal S (pixels from min_signal_adu up),
    fitted as var = s_bg^2 + S/g + (k S)^2 (s_bg fixed, weights from the bin counts). Returns
    (1/g [ADU/e-] with its 1-sigma from the weighted fit's covariance; it may be consistent with
    0 when shot noise is too small to see, k^2 [-], rows (S, var, count)).
    """
    signal, squared = residuals[:, 0], residuals[:, 1]
    use = signal >= min_signal_adu
    edges = np.geomspace(min_signal_adu, max(signal[use].max(), min_signal_adu * 2), bins + 1)
    index = np.digitize(signal[use], edges) - 1
    rows = []
    for b in range(bins):
        inside = index == b
        n = int(inside.sum())
        if n >= 8:
            rows.append((float(np.mean(signal[use][inside])), float(np.mean(squared[use][inside])), n))
    rows = np.array(rows, float).reshape(-1, 3)
    if len(rows) < 3:
        raise ValueError(f"photon transfer needs star pixels above {min_signal_adu:.1f} ADU in 3 bins, got {len(rows)}")
    s, var, n = rows.T
    excess = var - background_noise_adu ** 2
    # var of a sample variance ~ 2 var^2 / n
    weight = np.sqrt(n / 2.0) / var
    design = np.column_stack([s, s ** 2]) * weight[:, None]
    coef, *_ = np.linalg.lstsq(design, excess * weight, rcond=None)
    chi2 = float(np.sum((design @ coef - excess * weight) ** 2))
    cov = np.linalg.inv(design.T @ design) * max(chi2 / max(len(s) - 2, 1), 1.0)
    return Measured(float(coef[0]), float(np.sqrt(cov[0, 0]))), float(coef[1]), rows


def _robust_linear_fit(design: np.ndarray, values: np.ndarray, clip: float = 3.0):
    """
    Least squares with iterative clipping of residuals beyond `clip` sigma.

    (coefficients, their covariance scaled by the residual scatter).
    """
    keep = np.isfinite(values)
    for _ in range(5):
        coef, *_ = np.linalg.lstsq(design[keep], values[keep], rcond=None)
        residual = values - design @ coef
        scatter = float(np.std(residual[keep], ddof=design.shape[1]))
        new = np.isfinite(values) & (np.abs(residual) <= clip * scatter)
        if np.array_equal(new, keep) or new.sum() <= design.shape[1] + 1:
            break
        keep = new
    cov = np.linalg.inv(design[keep].T @ design[keep]) * scatter ** 2
    return coef, cov


def fit_zero_point(r2: np.ndarray, values: np.ndarray) -> tuple[Measured, Measured]:
    """
    Fit values = z0 + log10(1 - a r2) with a robust (soft L1) loss at the data's MAD scatter.

    r2 = r^2/r_c^2 of each star, values = log10 of its flux per second + 0.4 Hp. Returns (z0
    [log10 flux/s at Hp 0 at the centre], a [-]); 1-sigma from the Jacobian and the scatter.
    """
    def residual(p):
        return p[0] + np.log10(1.0 - p[1] * r2) - values

    start = np.array([float(np.median(values)), 0.0])
    scale = max(1.4826 * float(np.median(np.abs(values - np.median(values)))), 1e-3)
    fit = least_squares(residual, start, bounds=([-np.inf, -1.0], [np.inf, 0.99]), loss="soft_l1", f_scale=scale)
    final = fit.fun
    scatter = 1.4826 * float(np.median(np.abs(final - np.median(final))))
    try:
        cov = np.linalg.inv(fit.jac.T @ fit.jac) * scatter ** 2 * values.size / max(values.size - 2, 1)
    except np.linalg.LinAlgError:
        cov = np.full((2, 2), np.inf)
    return Measured(float(fit.x[0]), float(np.sqrt(cov[0, 0]))), Measured(float(fit.x[1]), float(np.sqrt(cov[1, 1])))


def robust_median(values: np.ndarray) -> Measured:
    """Median and its standard error (1.2533 x the MAD-based sigma / sqrt(n))."""
    values = np.asarray(values, float)[np.isfinite(values)]
    median = float(np.median(values))
    spread = 1.4826 * float(np.median(np.abs(values - median)))
    return Measured(median, 1.2533 * spread / np.sqrt(values.size))


def robust_mean(values: np.ndarray, clip: float = 3.0) -> Measured:
    """Mean and its standard error after iterative clipping at `clip` sigma."""
    values = np.asarray(values, float)
    keep = np.isfinite(values)
    for _ in range(5):
        mean, std = values[keep].mean(), values[keep].std(ddof=1)
        new = np.isfinite(values) & (np.abs(values - mean) <= clip * std)
        if np.array_equal(new, keep):
            break
        keep = new
    return Measured(float(values[keep].mean()), float(values[keep].std(ddof=1) / np.sqrt(keep.sum())))


# ------------------------------------------------------------------ the whole profile
def fit_camera_profile(frames: list[ProfileFrame], catalog: StarCatalog, psf_sigma_guess_px: float = 1.0,
                       saturation_adu: float = 255.0, tile_px: int = 64) -> CameraProfile:
    """
    Fit the profile to frames of one camera setting (same exposure and gain); see the module docstring for the methods.

    catalog: stars (Hp, B-V) at the frames' epoch, to a magnitude a little fainter than the
    faintest detected star.
    """
    if not frames:
        raise ValueError("need at least one frame")
    height, width = frames[0].image.shape
    exposure = frames[0].exposure_s
    if any(f.image.shape != (height, width) or f.exposure_s != exposure for f in frames):
        raise ValueError("all frames must share one image size and exposure")
    config = CentroidConfig(psf_sigma_px=psf_sigma_guess_px, saturation_adu=saturation_adu)
    # Background tiles, star-masked (detections and catalog stars), pooled over the frames.
    tiles, above = [], []
    for frame in frames:
        spots = extract_spots(frame.image, config)
        u, v, front = frame.camera.project(catalog.unit_vectors() @ frame.rotation)
        near = front & frame.camera.in_image(u, v, margin=-20)
        mask = star_mask(frame.image.shape, np.concatenate([spots.x, u[near]]), np.concatenate([spots.y, v[near]]),
                         radius_px=max(6.0 * psf_sigma_guess_px, 5.0))
        frame_tiles = tile_statistics(frame.image, mask, tile_px)
        tiles.append(frame_tiles)
        threshold = np.median(frame_tiles[:, 2]) + HOT_PIXEL_SIGMA * np.median(frame_tiles[:, 3])
        above.append(frame.image > threshold)
    tiles = np.concatenate(tiles)
    background, _, gradient = fit_background(tiles, width, height)
    noise = robust_mean(tiles[:, 3])
    noise = Measured(noise.value, float(np.std(tiles[:, 3], ddof=1)))  # tile-to-tile spread, not the mean's error
    fits, residuals = fit_stars(frames, catalog, config, noise.value)
    if fits.flux.size < 5:
        raise ValueError(f"only {fits.flux.size} identified isolated stars: too few to fit a profile")
    # Faint stars' widths (and fluxes) come out low: noise on the peak pixel narrows the fit.
    # PSF and photometry use the well-measured stars only.
    snr = fits.flux / (noise.value * np.sqrt(4.0 * np.pi) * np.median(fits.psf_sigma_px))
    used = snr >= MIN_SNR if np.sum(snr >= MIN_SNR) >= 5 else snr >= np.sort(snr)[-5]
    stars = StarFits(**{name: getattr(fits, name)[used] for name in StarFits.__dataclass_fields__})
    psf = robust_median(stars.psf_sigma_px)  # a few blends with unlisted stars fit wide: the median ignores them
    # Pixels from 2 s_bg up: there the clip at 0 no longer trims the noise.
    inverse_gain, model_error, ptc = photon_transfer_from_stars(residuals, noise.value, 2.0 * noise.value)
    # The binning is a choice: the spread of 1/g over other choices is added as a systematic error.
    variants = [photon_transfer_from_stars(residuals, noise.value, low * noise.value, bins)[0].value
                for low in (2.0, 3.0) for bins in (8, 12, 16)]
    inverse_gain = Measured(inverse_gain.value, float(np.hypot(inverse_gain.sigma, np.std(variants, ddof=1))))
    gain_is_lower_limit = not inverse_gain.value > 2.0 * inverse_gain.sigma
    if gain_is_lower_limit:  # shot noise not seen: the largest shot noise the data allow (2 sigma)
        gain = Measured(1.0 / (inverse_gain.value + 2.0 * inverse_gain.sigma), np.nan)
    else:
        gain = Measured(1.0 / inverse_gain.value, inverse_gain.sigma / inverse_gain.value ** 2)
    # Read noise from s^2 = (sigma_r/g)^2 + mu/g + 1/12 (rounding); its error from sampling 1/g, s and mu.
    rng = np.random.default_rng(0)
    inv_draw = np.abs(rng.normal(inverse_gain.value, inverse_gain.sigma, 4000))
    s_draw = rng.normal(noise.value, noise.sigma / np.sqrt(len(tiles)), 4000)
    mu_draw = np.maximum(rng.normal(background.value, background.sigma, 4000), 0.0)
    read_draw = np.sqrt(np.maximum(s_draw ** 2 - ROUNDING_VAR - mu_draw * inv_draw, 0.0)) / inv_draw
    read_adu2 = noise.value ** 2 - ROUNDING_VAR - max(background.value, 0.0) / gain.value
    read_value = float(gain.value * np.sqrt(max(read_adu2, 0.0)))
    read_noise = Measured(read_value, np.nan if gain_is_lower_limit else float(np.std(read_draw)))
    # Zero point and vignetting: log10 of each star's ADU/s + 0.4 Hp = log10(zp) + log10(1 - a r^2/r_c^2)
    # (the renderer's vignetting); then the free slope and colour on the vignetting-corrected fluxes.
    log_rate = np.log10(np.maximum(stars.flux, 1e-9) / exposure)  # ADU/s: independent of the gain
    r2 = radius_squared(stars.x, stars.y, width, height)
    zero_point, vignetting = fit_zero_point(r2, log_rate + 0.4 * stars.hp)
    flat = log_rate - np.log10(1.0 - vignetting.value * r2)  # vignetting removed
    coef, cov = _robust_linear_fit(np.column_stack([np.ones_like(r2), stars.hp]), flat)
    free_slope = Measured(float(coef[1]), float(np.sqrt(cov[1, 1])))
    coef, cov = _robust_linear_fit(np.column_stack([np.ones_like(r2), -0.4 * stars.b_v]), flat + 0.4 * stars.hp)
    color = Measured(float(coef[1]), float(np.sqrt(cov[1, 1])))
    hot = np.zeros((height, width), bool)
    if len(frames) >= 3:
        hot = np.mean(above, axis=0) >= HOT_PIXEL_FRACTION_OF_FRAMES
    hot_level = 0.0
    if hot.any():
        hot_level = float(np.median(np.mean([f.image[hot] for f in frames], axis=0))) - background.value
    bright = stars.flux > 20 * noise.value  # wing excess only where the aperture sum is precise
    wings = Measured(np.nan, np.nan)
    if bright.sum() >= 3:
        wings = robust_mean(stars.aperture_flux[bright] / stars.flux[bright] - 1.0)
    return CameraProfile(
        gain_e_per_adu=gain, inverse_gain_adu_per_e=inverse_gain, gain_is_lower_limit=gain_is_lower_limit,
        read_noise_e=read_noise, psf_sigma_px=psf, background_adu=background,
        background_noise_adu=noise, vignetting_at_corner=vignetting, gradient_adu_per_px=gradient,
        log10_zero_point_adu_per_s=zero_point, zero_point_free_slope=free_slope, color_coefficient=color,
        hot_pixel_fraction=float(hot.mean()), hot_pixel_level_adu=hot_level, psf_wing_excess=wings,
        exposure_s=exposure, width=width, height=height, n_frames=len(frames), stars=fits, used=used, ptc=ptc,
        tiles=tiles, ptc_model_error=model_error)
