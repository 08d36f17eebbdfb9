"""CentroidConfig: the parameters of the centroiding stage, and the limits derived from them."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import erf

from .measure import star_peak_to_neighbour_ratio

CENTROID_METHODS = ("auto", "cog", "wcog", "gaussian", "streak")
PSF_MODES = ("auto", "fixed")


@dataclass(frozen=True)
class CentroidConfig:
    """Parameters of `extract_spots` (the centroider node's parameters, same names).

    detection_sigma: threshold in units of the noise of the PSF-matched detection image;
    binning: detection grid bin factor (1 or 2; 2 is 4x cheaper and splits pairs >= ~4 px);
    min_area/max_area: accepted footprint sizes [full-resolution px]; min_snr: reported spots'
    SNR floor; background_block_px: background mesh size [px]; gain_e_per_adu: for the
    shot-noise term of the covariance; saturation_adu: a spot with a pixel at or above it is
    flagged (0 = the image dtype's maximum); max_spots: keep at most this many (brightest).
    psf_sigma_px: the optics' PSF 1-sigma [px]; sets the fit model, windows, hot-pixel test.
    With psf_mode "auto" (default) it is the prior: each frame's PSF is estimated from its
    bright isolated stars (psf_estimate.py) and the frame measured with that width when it
    differs from the prior by more than 10 %; "fixed" uses psf_sigma_px as given. 0 means no
    PSF (no shape test, no estimate: centre of gravity methods only).
    Shape test (hot pixels, cosmic rays; psf_sigma_px > 0): isolated pixels brighter than a
    PSF allows are replaced by their neighbours' mean first; then a spot is rejected when its
    brightest pixel holds more than max_peak_fraction of its flux (raised for an undersampled
    PSF to what a star centred on a pixel gives, see peak_fraction_limit), or, at SNR >= shape_min_snr,
    when its narrowest second moment is below min_width_fraction * psf_sigma_px^2 (a star is
    never thinner than the PSF; a cosmic-ray track is).
    method: "auto" (default) = PSF fit for point-like spots, streak model for elongated ones;
    "gaussian" = PSF fit for point-like spots, centre of gravity for streaks; "streak" = streak
    model for every spot; "cog" = centre of gravity; "wcog" = intensity-weighted (squared)
    centre of gravity. Saturated spots always use the centre of gravity.
    split_blends: fit two PSFs jointly when a point-like spot shows a second peak.
    min_smear_px: with a known body rate, predicted smears shorter than this are point-like.
    """

    detection_sigma: float = 4.5
    binning: int = 2
    min_area: int = 2
    max_area: int = 20000
    min_snr: float = 5.0
    background_block_px: int = 32
    gain_e_per_adu: float = 1.0
    saturation_adu: float = 0.0
    max_spots: int = 500
    method: str = "auto"
    psf_sigma_px: float = 1.0
    psf_mode: str = "auto"
    max_peak_fraction: float = 0.5
    min_width_fraction: float = 0.6
    shape_min_snr: float = 10.0
    split_blends: bool = True
    min_smear_px: float = 1.5

    def __post_init__(self) -> None:
        bad = []
        if not (np.isfinite(self.detection_sigma) and self.detection_sigma > 0):
            bad.append(f"detection_sigma={self.detection_sigma} must be > 0")
        if self.binning not in (1, 2):
            bad.append(f"binning={self.binning} must be 1 or 2")
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
        if self.psf_mode not in PSF_MODES:
            bad.append(f"psf_mode={self.psf_mode!r} must be one of {PSF_MODES}")
        if self.method not in CENTROID_METHODS:
            bad.append(f"method={self.method!r} must be one of {CENTROID_METHODS}")
        if self.method in ("auto", "gaussian", "streak") and self.psf_sigma_px <= 0:
            bad.append(f"method {self.method!r} needs psf_sigma_px > 0")
        if not (0 < self.max_peak_fraction <= 1 and 0 <= self.min_width_fraction <= 1 and self.shape_min_snr >= 0):
            bad.append("need 0 < max_peak_fraction <= 1, 0 <= min_width_fraction <= 1, shape_min_snr >= 0")
        if not (np.isfinite(self.min_smear_px) and self.min_smear_px >= 0):
            bad.append(f"min_smear_px={self.min_smear_px} must be >= 0")
        if bad:
            raise ValueError("invalid centroid config: " + "; ".join(bad))

    @property
    def window_half(self) -> int:
        """Half size of a point-spot window [px]: the PSF to 3 sigma (beyond, a
        pixel carries < 1 % of the position information)."""
        return int(max(3, np.ceil(3.0 * max(self.psf_sigma_px, 1.0))))


def elongation_limit(sigma: float) -> float:
    """Largest second moment [px^2] of a point-like spot: 2.5x a pixelated PSF's (a segment of
    length L adds L^2 / 12), the PSF taken at least 0.6 px wide: the noise in a faint spot's
    aperture adds ~0.2-0.4 px^2 to its moments, which a sharper PSF's limit would call a
    streak."""
    return 2.5 * (max(sigma, 0.6) ** 2 + 1.0 / 12.0)


def hot_pixel_ratio(config: CentroidConfig, sigma: float) -> float:
    """Peak-to-brightest-neighbour ratio above which a pixel is a defect, not starlight
    (twice what the PSF allows); inf (no cleaning) without a PSF."""
    return 2.0 * star_peak_to_neighbour_ratio(sigma) if config.psf_sigma_px > 0 else np.inf


def peak_fraction_limit(config: CentroidConfig, sigma: float) -> float:
    """Largest share of a spot's flux its brightest pixel may hold [-]: max_peak_fraction, or
    for a PSF so narrow that a star centred on a pixel puts more than that in it, 1.3x that
    share (at most 0.95: a hot pixel holds all of it)."""
    centred = float(erf(0.5 / (np.sqrt(2.0) * max(sigma, 1e-3))) ** 2)
    return max(config.max_peak_fraction, min(0.95, 1.3 * centred))
