# SPDX-License-Identifier: Apache-2.0
"""
A second star-field renderer, written independently of star_tracker.sim (it imports nothing from it).

A centroiding benchmark run on it does not share the simulator's assumptions.

PSFs (each a normalised 2-D density integrated over every pixel's square):
- `GaussianPsf`: analytic pixel integral (erf at the pixel edges);
- `EllipticalGaussianPsf`, `MoffatPsf`, `AnnulusPsf`: the density integrated by Gauss–Legendre
  supersampling of each pixel (n x n nodes); the annulus (a defocused pupil: a uniform ring
  convolved with a Gaussian blur) is evaluated through its exact radial profile
  f(r) = 1/A ∫ ρ exp(-(r-ρ)^2 / 2b^2) I0e(rρ/b^2) / b^2 dρ over the ring, A = π(r_out^2 - r_in^2).

Detector (`Detector`, its own noise code): expected electrons = sky + stars + hot-pixel dark
charge; Poisson draw of all of it; cosmic-ray charge (short 1-2 px wide tracks) added; Gaussian
read noise; clipping at the full well (or, `blooms`, the charge above it moved along the column,
half each way, into the nearest pixels with room); gain, bias, rounding, clipping to the ADC
range (12 or 16 bit).

Pixel convention: (x, y) = (column, row), (0, 0) = centre of the top-left pixel, so pixel
(r, c) covers x in [c - 0.5, c + 0.5], y in [r - 0.5, r + 0.5]. Fluxes in electrons [e-].

`cramer_rao` is the Fisher bound of (x, y) for each star from its own PSF and the noise
model: I = sum_i grad(mu_i) grad(mu_i)^T / var_i, var_i = mu_i + sky + read^2 + gain^2/12
(flux and sky known; for a PSF symmetric under inversion position decouples from them),
grad by central differences of the pixel-integrated model.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.special import erf, i0e

SIGMA_PER_FWHM = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))


def _gauss_legendre_unit(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes on [-0.5, 0.5] and weights summing to 1."""
    nodes, weights = np.polynomial.legendre.leggauss(n)
    return 0.5 * nodes, 0.5 * weights


class _SupersampledPsf:
    """
    A PSF given by a point density [1/px^2] (`density(dx, dy)`).

    Integrated over each pixel with `nodes` x `nodes` Gauss–Legendre points.
    """

    def pixel_fractions(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """
        Return the fraction of the star's light in pixels whose centres are at (dx, dy) [px].

        dx, dy: offsets from the star, broadcast arrays of one shape.
        """
        t, w = _gauss_legendre_unit(self.nodes)
        px = dx[..., None, None] + t[None, :]
        py = dy[..., None, None] + t[:, None]
        return np.einsum("...ij,i,j->...", self.density(px, py), w, w)


@dataclass(frozen=True)
class GaussianPsf:
    """Circular Gaussian of 1-sigma `sigma_px` [px]."""

    sigma_px: float

    @property
    def equivalent_sigma_px(self) -> float:
        return self.sigma_px

    def support_radius_px(self) -> int:
        return int(np.ceil(6.0 * self.sigma_px)) + 1

    def pixel_fractions(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        s = 1.0 / (np.sqrt(2.0) * self.sigma_px)
        fx = 0.5 * (erf((dx + 0.5) * s) - erf((dx - 0.5) * s))
        fy = 0.5 * (erf((dy + 0.5) * s) - erf((dy - 0.5) * s))
        return fx * fy

    def label(self) -> str:
        return f"Gaussian σ {self.sigma_px:g}"


@dataclass(frozen=True)
class EllipticalGaussianPsf(_SupersampledPsf):
    """
    Gaussian with 1-sigma widths sigma_major_px >= sigma_minor_px [px].

    Major axis at angle_rad [rad] from +x toward +y.
    """

    sigma_major_px: float
    sigma_minor_px: float
    angle_rad: float

    @property
    def equivalent_sigma_px(self) -> float:
        return float(np.sqrt(self.sigma_major_px * self.sigma_minor_px))

    @property
    def nodes(self) -> int:
        return int(np.clip(np.ceil(4.0 / self.sigma_minor_px), 6, 16))

    def support_radius_px(self) -> int:
        return int(np.ceil(6.0 * self.sigma_major_px)) + 1

    def density(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        c, s = np.cos(self.angle_rad), np.sin(self.angle_rad)
        u, v = c * dx + s * dy, -s * dx + c * dy
        a, b = self.sigma_major_px, self.sigma_minor_px
        return np.exp(-0.5 * ((u / a) ** 2 + (v / b) ** 2)) / (2.0 * np.pi * a * b)

    def label(self) -> str:
        return (f"elliptical σ {self.sigma_major_px:.2f}/{self.sigma_minor_px:.2f} "
                f"at {np.degrees(self.angle_rad):.0f}°")


@dataclass(frozen=True)
class MoffatPsf(_SupersampledPsf):
    """
    Moffat profile (β - 1)/(π α^2) (1 + r^2/α^2)^-β of full width at half maximum `fwhm_px` [px].

    `wing_fraction`: the light beyond the rendered stamp (its truncation).
    """

    fwhm_px: float
    beta: float = 3.0
    wing_fraction: float = 1e-3

    @property
    def alpha_px(self) -> float:
        return self.fwhm_px / (2.0 * np.sqrt(2.0 ** (1.0 / self.beta) - 1.0))

    @property
    def equivalent_sigma_px(self) -> float:
        """The Gaussian sigma of the same FWHM [px]."""
        return self.fwhm_px * SIGMA_PER_FWHM

    @property
    def nodes(self) -> int:
        return int(np.clip(np.ceil(4.0 / self.alpha_px), 6, 16))

    def support_radius_px(self) -> int:
        # Light beyond radius R: (1 + R^2/α^2)^(1-β) = wing_fraction.
        radius = self.alpha_px * np.sqrt(self.wing_fraction ** (1.0 / (1.0 - self.beta)) - 1.0)
        return int(np.ceil(radius)) + 1

    def density(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        a2 = self.alpha_px ** 2
        return (self.beta - 1.0) / (np.pi * a2) * (1.0 + (dx * dx + dy * dy) / a2) ** (-self.beta)

    def label(self) -> str:
        return f"Moffat β {self.beta:g}, FWHM {self.fwhm_px:.2f}"


@dataclass(frozen=True)
class AnnulusPsf(_SupersampledPsf):
    """
    A defocused pupil.

    Uniform ring between inner_radius_px and outer_radius_px [px] convolved with a Gaussian
    blur of 1-sigma blur_px [px].
    """

    outer_radius_px: float
    inner_radius_px: float
    blur_px: float
    _table: tuple = field(default=(), init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        r_in, r_out, b = self.inner_radius_px, self.outer_radius_px, self.blur_px
        r = np.linspace(0.0, r_out + 8.0 * b, 2048)
        rho, w = np.polynomial.legendre.leggauss(256)
        rho = r_in + (rho + 1.0) * 0.5 * (r_out - r_in)
        w = w * 0.5 * (r_out - r_in)
        # The ring's light at distance r from the centre, azimuth integrated exactly (I0).
        x = r[:, None] * rho[None, :] / b ** 2
        kernel = np.exp(-((r[:, None] - rho[None, :]) ** 2) / (2 * b ** 2)) * i0e(x) / b ** 2
        profile = (kernel * rho[None, :] * w[None, :]).sum(axis=1) / (r_out ** 2 - r_in ** 2)
        object.__setattr__(self, "_table", (r, profile / np.pi))

    @staticmethod
    def with_equivalent_sigma(sigma_px: float, inner_fraction: float = 0.5, blur_fraction: float = 0.3) -> "AnnulusPsf":
        """
        Return the annulus whose per-axis second moment (r_out^2 + r_in^2)/4 + b^2 equals sigma_px^2.

        With r_in = inner_fraction r_out and b = blur_fraction sigma_px.
        """
        blur = blur_fraction * sigma_px
        outer = np.sqrt(4.0 * (sigma_px ** 2 - blur ** 2) / (1.0 + inner_fraction ** 2))
        return AnnulusPsf(float(outer), float(inner_fraction * outer), float(blur))

    @property
    def equivalent_sigma_px(self) -> float:
        return float(np.sqrt((self.outer_radius_px ** 2 + self.inner_radius_px ** 2) / 4.0 + self.blur_px ** 2))

    @property
    def nodes(self) -> int:
        return int(np.clip(np.ceil(3.0 / self.blur_px), 6, 16))

    def support_radius_px(self) -> int:
        return int(np.ceil(self.outer_radius_px + 6.0 * self.blur_px)) + 1

    def density(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        r, profile = self._table
        return np.interp(np.hypot(dx, dy), r, profile, right=0.0)

    def label(self) -> str:
        return (f"annulus r {self.inner_radius_px:.2f}-{self.outer_radius_px:.2f}, "
                f"blur {self.blur_px:.2f}")


@dataclass(frozen=True)
class Detector:
    """
    Sky and detector.

    sky_e [e-/px per exposure]; read_noise_e [e-]; gain_e_per_adu; bias_adu; full_well_e
    [e-]; adc_bits (12 or 16); hot pixels: hot_pixel_fraction of the pixels carry a fixed
    dark charge log-uniform in hot_pixel_e [e-] (positions from hot_pixel_seed: the same in
    every frame); cosmic rays: cosmic_rays_per_frame tracks on average, lengths in
    cosmic_ray_length_px [px], widths 1-2 px, total charge log-uniform in cosmic_ray_e [e-].
    """

    sky_e: float = 40.0
    read_noise_e: float = 5.0
    gain_e_per_adu: float = 1.0
    bias_adu: float = 100.0
    full_well_e: float = 60000.0
    adc_bits: int = 16
    hot_pixel_fraction: float = 0.0
    hot_pixel_e: tuple[float, float] = (500.0, 20000.0)
    hot_pixel_seed: int = 0
    cosmic_rays_per_frame: float = 0.0
    cosmic_ray_length_px: tuple[float, float] = (2.0, 12.0)
    cosmic_ray_e: tuple[float, float] = (1000.0, 30000.0)
    blooms: bool = False

    def __post_init__(self) -> None:
        if self.adc_bits not in (12, 16):
            raise ValueError(f"adc_bits={self.adc_bits} must be 12 or 16")
        if min(self.sky_e, self.read_noise_e, self.bias_adu, self.hot_pixel_fraction, self.cosmic_rays_per_frame) < 0 \
                or self.gain_e_per_adu <= 0 or self.full_well_e <= 0:
            raise ValueError("detector levels must be >= 0, gain and full well > 0")

    @property
    def pixel_variance_e2(self) -> float:
        """Variance of a star-free pixel [e-^2]: sky shot noise, read noise, quantisation."""
        return self.sky_e + self.read_noise_e ** 2 + self.gain_e_per_adu ** 2 / 12.0


class Stamp(NamedTuple):
    """One star's light: fractions (h, w) of its flux in the pixels from (row0, col0)."""

    row0: int
    col0: int
    fractions: np.ndarray


def star_stamp(psf, x: float, y: float, window_x: float | None = None, window_y: float | None = None) -> Stamp:
    """
    Return the pixel fractions of a star at (x, y) [px] over its PSF's support.

    Centred on the pixel nearest (window_x, window_y) (default: the star itself).
    """
    half = psf.support_radius_px()
    col0 = int(np.rint(x if window_x is None else window_x)) - half
    row0 = int(np.rint(y if window_y is None else window_y)) - half
    cols = np.arange(col0, col0 + 2 * half + 1)
    rows = np.arange(row0, row0 + 2 * half + 1)
    return Stamp(row0, col0, psf.pixel_fractions(cols[None, :] - x, rows[:, None] - y))


def place_stars(width: int, height: int, count: int, min_separation_px: float, margin_px: float,
                rng: np.random.Generator, attempts: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """
    Up to `count` uniformly random positions [px] (sub-pixel).

    At least `margin_px` from the borders and `min_separation_px` from each other (dart
    throwing).
    """
    xs: list[float] = []
    ys: list[float] = []
    for _ in range(attempts):
        if len(xs) == count:
            break
        x = rng.uniform(margin_px, width - 1 - margin_px)
        y = rng.uniform(margin_px, height - 1 - margin_px)
        if not xs or np.min(np.hypot(np.asarray(xs) - x, np.asarray(ys) - y)) >= min_separation_px:
            xs.append(x)
            ys.append(y)
    return np.asarray(xs), np.asarray(ys)


@dataclass(frozen=True)
class StarField:
    """
    Stars at fixed positions x, y [px] with one PSF.

    Their stamps (pixel fractions) and the fractions' derivatives along x and y [1/px]
    (central differences of step_px on the same window, for the Cramér–Rao bound) are computed
    once and reused for every flux and noise draw.
    """

    psf: object
    x: np.ndarray
    y: np.ndarray
    stamps: tuple[Stamp, ...]
    gradients: tuple[tuple[np.ndarray, np.ndarray], ...]

    @staticmethod
    def build(psf, x: np.ndarray, y: np.ndarray, step_px: float = 1e-3) -> "StarField":
        x, y = np.asarray(x, float), np.asarray(y, float)
        stamps, gradients = [], []
        for xk, yk in zip(x, y):
            def shifted(ddx: float, ddy: float) -> np.ndarray:
                return star_stamp(psf, xk + ddx, yk + ddy, xk, yk).fractions

            stamps.append(star_stamp(psf, xk, yk))
            gradients.append(((shifted(step_px, 0.0) - shifted(-step_px, 0.0)) / (2 * step_px),
                              (shifted(0.0, step_px) - shifted(0.0, -step_px)) / (2 * step_px)))
        return StarField(psf, x, y, tuple(stamps), tuple(gradients))

    def deposited_fractions(self, width: int, height: int) -> np.ndarray:
        """Share of each star's light that lands on the chip inside its stamp [-]."""
        return np.array([_clipped(s, width, height)[2].sum() for s in self.stamps])


def _clipped(stamp: Stamp, width: int, height: int):
    r0, c0 = max(stamp.row0, 0), max(stamp.col0, 0)
    h, w = stamp.fractions.shape
    r1, c1 = min(stamp.row0 + h, height), min(stamp.col0 + w, width)
    return slice(r0, r1), slice(c0, c1), stamp.fractions[r0 - stamp.row0:r1 - stamp.row0,
                                                         c0 - stamp.col0:c1 - stamp.col0]


class Truth(NamedTuple):
    """
    What one frame holds.

    Stars: x, y [px], flux_e: the electrons each put on the chip (expected) [e-], snr:
    optimal (PSF-weighted) SNR [-]. Defects: hot pixels (fixed) and cosmic rays: their
    centre x, y [px], charge [e-], extent [px] (1 for a hot pixel).
    """

    x: np.ndarray
    y: np.ndarray
    flux_e: np.ndarray
    snr: np.ndarray
    defect_x: np.ndarray
    defect_y: np.ndarray
    defect_e: np.ndarray
    defect_extent_px: np.ndarray
    defect_is_cosmic_ray: np.ndarray


class Frame(NamedTuple):
    image: np.ndarray  # uint16 (height, width) [ADU]
    truth: Truth


def star_signal(field_: StarField, flux_e: float, width: int, height: int) -> np.ndarray:
    """
    Return the expected star electrons per pixel (float64, (height, width)) for every star.

    At the nominal flux `flux_e` [e-]; the light outside the chip or stamp is lost.
    """
    signal = np.zeros((height, width))
    for stamp in field_.stamps:
        rows, cols, fractions = _clipped(stamp, width, height)
        signal[rows, cols] += flux_e * fractions
    return signal


def hot_pixels(detector: Detector, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the detector's fixed hot pixels: columns, rows, dark charge [e-]."""
    rng = np.random.default_rng([detector.hot_pixel_seed, width, height])
    count = int(round(detector.hot_pixel_fraction * width * height))
    index = rng.choice(width * height, size=count, replace=False)
    low, high = np.log(detector.hot_pixel_e[0]), np.log(detector.hot_pixel_e[1])
    return index % width, index // width, np.exp(rng.uniform(low, high, count))


def cosmic_rays(detector: Detector, width: int, height: int, rng: np.random.Generator):
    """
    One frame's cosmic-ray charge (float64 image [e-]) and listing (x, y centres [px], charge [e-], length [px]).

    A track is sampled every 0.05 px along its length and uniformly across its width (1-2
    px); each sample's charge goes to the pixel it falls in.
    """
    charge = np.zeros((height, width))
    count = rng.poisson(detector.cosmic_rays_per_frame)
    cx, cy = rng.uniform(0, width - 1, count), rng.uniform(0, height - 1, count)
    length = rng.uniform(*detector.cosmic_ray_length_px, count)
    thickness = rng.uniform(1.0, 2.0, count)
    heading = rng.uniform(0.0, np.pi, count)
    energy = np.exp(rng.uniform(np.log(detector.cosmic_ray_e[0]), np.log(detector.cosmic_ray_e[1]), count))
    for k in range(count):
        samples = max(int(length[k] / 0.05), 2)
        along = rng.uniform(-0.5, 0.5, samples) * length[k]
        across = rng.uniform(-0.5, 0.5, samples) * thickness[k]
        c, s = np.cos(heading[k]), np.sin(heading[k])
        cols = np.rint(cx[k] + along * c - across * s).astype(int)
        rows = np.rint(cy[k] + along * s + across * c).astype(int)
        inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
        np.add.at(charge, (rows[inside], cols[inside]), energy[k] / samples)
    return charge, (cx, cy, energy, length)


def optimal_snr(field_: StarField, flux_e: float, detector: Detector) -> np.ndarray:
    """
    Each star's SNR with an optimal PSF-weighted aperture [-].

    SNR = F sqrt(sum_i p_i^2 / (F p_i + sky + read^2 + gain^2/12)), p_i its pixel fractions.
    """
    return np.array([flux_e * np.sqrt(np.sum(s.fractions ** 2 / (flux_e * s.fractions + detector.pixel_variance_e2)))
                     for s in field_.stamps])


def expose(star_e: np.ndarray, detector: Detector, rng: np.random.Generator):
    """
    Read expected star electrons per pixel `star_e` (height, width) [e-] through the detector.

    Returns the image [ADU] (uint16), the hot pixels (columns, rows, dark charge [e-]) and the
    cosmic rays (x, y centres [px], charge [e-], length [px]).
    """
    height, width = star_e.shape
    expected = star_e + detector.sky_e
    hot_cols, hot_rows, hot_e = hot_pixels(detector, width, height)
    expected[hot_rows, hot_cols] += hot_e
    electrons = rng.poisson(expected).astype(np.float64)
    ray_charge, rays = cosmic_rays(detector, width, height, rng)
    electrons += ray_charge
    electrons += rng.normal(0.0, detector.read_noise_e, electrons.shape)
    if detector.blooms:
        _bloom(electrons, detector.full_well_e)
    electrons = np.minimum(electrons, detector.full_well_e)
    adu = np.rint(electrons / detector.gain_e_per_adu + detector.bias_adu)
    image = np.clip(adu, 0, 2 ** detector.adc_bits - 1).astype(np.uint16)
    return image, (hot_cols, hot_rows, hot_e), rays


def render(field_: StarField, flux_e: float, detector: Detector, width: int, height: int,
           rng: np.random.Generator) -> Frame:
    """One frame [ADU] of the star field at flux `flux_e` [e-] per star, with its truth."""
    image, (hot_cols, hot_rows, hot_e), (ray_x, ray_y, ray_e, ray_length) = expose(
        star_signal(field_, flux_e, width, height), detector, rng)
    truth = Truth(field_.x, field_.y, flux_e * field_.deposited_fractions(width, height),
                  optimal_snr(field_, flux_e, detector),
                  np.r_[hot_cols.astype(float), ray_x], np.r_[hot_rows.astype(float), ray_y], np.r_[hot_e, ray_e],
                  np.r_[np.ones(hot_e.size), ray_length], np.r_[np.zeros(hot_e.size, bool), np.ones(ray_e.size, bool)])
    return Frame(image, truth)


def _bloom(electrons: np.ndarray, full_well_e: float) -> None:
    """Move each pixel's charge above full_well_e [e-] along its column, half up and half down, pixel by pixel."""
    height = electrons.shape[0]
    for col in np.flatnonzero((electrons > full_well_e).any(axis=0)):
        column = electrons[:, col]
        for row in np.flatnonzero(column > full_well_e):
            excess = column[row] - full_well_e
            if excess <= 0.0:
                continue
            column[row] = full_well_e
            for step in (-1, 1):
                left, r = 0.5 * excess, row + step
                while left > 0.0 and 0 <= r < height:
                    take = min(max(full_well_e - column[r], 0.0), left)
                    column[r] += take
                    left -= take
                    r += step


def cramer_rao(field_: StarField, flux_e: float, detector: Detector) -> np.ndarray:
    """
    Return the (N, 2, 2) Cramér–Rao bound of each star's (x, y) [px^2] at flux `flux_e` [e-].

    See the module docstring; the star's own light only: the fields are isolated stars.
    """
    bounds = np.empty((len(field_.x), 2, 2))
    for k, (stamp, (dx, dy)) in enumerate(zip(field_.stamps, field_.gradients)):
        var = flux_e * stamp.fractions + detector.pixel_variance_e2
        gx, gy = flux_e * dx, flux_e * dy
        info = np.array([[np.sum(gx * gx / var), np.sum(gx * gy / var)],
                         [np.sum(gx * gy / var), np.sum(gy * gy / var)]])
        bounds[k] = np.linalg.inv(info)
    return bounds
