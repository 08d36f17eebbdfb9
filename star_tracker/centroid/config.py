# SPDX-License-Identifier: Apache-2.0
"""CentroidConfig: the parameters of the centroiding stage, and the limits derived from them."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import erf

from ..parameter_spec import parameter, range_problems
from .detection.measure import star_peak_to_neighbour_ratio

CENTROID_METHODS = ("auto", "cog", "wcog", "gaussian", "streak")
PSF_MODES = ("auto", "fixed")


@dataclass(frozen=True)
class CentroidConfig:
    """
    Parameters of `extract_spots`, the centroider node's parameters (same names).

    Default, unit, range and description of each are in its field's `parameter(...)`
    (parameter_spec.py).

    detection_sigma: threshold in units of the noise of the PSF-matched detection image;
    binning: detection grid bin factor (1 or 2; 2 is 4x cheaper and splits pairs >= ~4 px);
    min_area/max_area: accepted footprint sizes [full-resolution px]; min_snr: reported spots'
    SNR floor; background_block_px: background mesh size [px]; gain_e_per_adu: for the
    shot-noise term of the covariance; saturation_adu: a spot with a pixel at or above it is
    flagged (0 = the image dtype's maximum); max_spots: keep at most this many (brightest).
    psf_sigma_px: the optics' PSF 1-sigma [px]; sets the fit model, windows, hot-pixel test.
    With psf_mode "auto" (default) it is the prior: each frame's PSF is estimated from its
    bright isolated stars (psf/estimate.py) and the frame measured with that width when it
    differs from the prior by more than 10 %; "fixed" uses psf_sigma_px as given. 0 means no
    PSF (no shape test, no estimate: centre of gravity methods only).
    Shape test (hot pixels, cosmic rays; psf_sigma_px > 0): isolated pixels brighter than a
    PSF allows are replaced by their neighbours' mean first; then a spot is rejected when its
    brightest pixel holds more than max_peak_fraction of its flux (raised for an undersampled
    PSF to what a star centred on a pixel gives, see peak_fraction_limit; x (1 + 2/SNR) for
    its noise), or, at SNR >= shape_min_snr, when its narrowest second moment is below
    min_width_fraction * psf_sigma_px^2 (a star is never thinner than the PSF; a cosmic-ray
    track is; an estimated elongated PSF's minor axis in place of psf_sigma_px).
    method: "auto" (default) = PSF fit for point-like spots, streak model for elongated ones;
    "gaussian" = PSF fit for point-like spots, centre of gravity for streaks; "streak" = streak
    model for every spot; "cog" = centre of gravity; "wcog" = intensity-weighted (squared)
    centre of gravity. Saturated spots always use the centre of gravity.
    split_blends: fit two PSFs jointly when a point-like spot shows a second peak.
    min_smear_px: with a known body rate, predicted smears shorter than this are point-like.
    texture_last: elongated spots pointing every way (texture.py) ranked after the point-like
    ones for the fits and max_spots (default off: bloated stars can point every way too).
    sensor_blooms: the sensor spills the charge above its full well along its columns, so
    the pixel past each end of a clipped run is no PSF's (detection/saturation.py), and a
    clipped star elongated along its column in a frame not smeared is a point (frame_fits).
    """

    detection_sigma: float = parameter(4.5, "detection threshold on the PSF-matched, binned image", "noise sigmas",
                                       1.0, 100.0, dynamic=True)
    binning: int = parameter(2, "detection grid bin factor: 2 = 4x cheaper, splits pairs >= ~4 px; 1 = full "
                             "resolution", "", 1, 2, dynamic=True)
    min_area: int = parameter(2, "smallest accepted footprint", "px", 1, 10000, dynamic=True)
    max_area: int = parameter(20000, "largest accepted footprint", "px", 1, 1000000, dynamic=True)
    min_snr: float = parameter(5.0, "smallest reported SNR", "-", 0.0, 1e6, dynamic=True)
    background_block_px: int = parameter(32, "background mesh size", "px", 4, 1024, dynamic=True)
    gain_e_per_adu: float = parameter(1.0, "sensor gain for the shot-noise term", "e-/ADU", 1e-3, 1e4, dynamic=True)
    saturation_adu: float = parameter(0.0, "saturation level: a spot with a pixel at or above it is flagged; 0 = the "
                                      "image dtype's maximum (flat tops are found either way)", "ADU", 0.0, 1e9,
                                      dynamic=True)
    max_spots: int = parameter(500, "most spots reported per frame (the brightest)", "", 1, 100000, dynamic=True)
    method: str = parameter("auto", "sub-pixel method (auto = PSF fit for points, streak model for streaks)",
                            choices=CENTROID_METHODS, dynamic=True)
    psf_sigma_px: float = parameter(1.0, "PSF 1-sigma of the optics: the prior of the estimate (psf_mode auto) or the "
                                    "width used (fixed); 0 = no PSF, no shape test", "px", 0.0, 50.0, dynamic=True)
    psf_mode: str = parameter("auto", "PSF width: auto = estimated on every frame from its stars, carried to the "
                              "next; fixed = psf_sigma_px", choices=PSF_MODES, dynamic=True)
    max_peak_fraction: float = parameter(0.5, "reject a spot whose brightest pixel holds more of its flux (hot "
                                         "pixels)", "-", 0.01, 1.0, dynamic=True)
    min_width_fraction: float = parameter(0.6, "reject a spot narrower than this x psf_sigma_px^2 (cosmic rays)", "-",
                                          0.0, 1.0, dynamic=True)
    shape_min_snr: float = parameter(10.0, "smallest SNR for the width test", "-", 0.0, 1e6, dynamic=True)
    split_blends: bool = parameter(True, "fit two PSFs when a point-like spot has a second peak", dynamic=True)
    min_smear_px: float = parameter(1.5, "predicted smears shorter than this are point-like", "px", 0.0, 1e4,
                                    dynamic=True)
    texture_last: bool = parameter(False, "where >= 30 elongated spots (no known rate) point every way (texture such "
                                   "as a lit cloud, not smear), keep the point-like ones first for the fits and "
                                   "max_spots", dynamic=True)
    sensor_blooms: bool = parameter(False, "the sensor spills charge above its full well along its columns (a CCD "
                                    "without anti-blooming; the simulator in orbit): the pixel past each end of a "
                                    "clipped run is left out of the fits", dynamic=True)

    def __post_init__(self) -> None:
        bad = range_problems(self)
        if self.min_area > self.max_area:
            bad.append(f"need min_area ({self.min_area}) <= max_area ({self.max_area})")
        if self.method in ("auto", "gaussian", "streak") and self.psf_sigma_px <= 0:
            bad.append(f"method {self.method!r} needs psf_sigma_px > 0")
        if bad:
            raise ValueError("invalid centroid config: " + "; ".join(bad))


def window_half(sigma: float) -> int:
    """
    Half size of a point-spot window [px] for a PSF of 1-sigma `sigma` [px].

    The PSF to 3 sigma (beyond, a pixel carries < 1 % of the position information), at least 3.
    """
    return int(max(3, np.ceil(3.0 * max(sigma, 1.0))))


def elongation_limit(sigma: float) -> float:
    """
    Largest second moment [px^2] of a point-like spot.

    2.5x a pixelated PSF's (a segment of length L adds L^2 / 12), the PSF taken at least 0.6
    px wide: the noise in a faint spot's aperture adds ~0.2-0.4 px^2 to its moments, which a
    sharper PSF's limit would call a streak.
    """
    return 2.5 * (max(sigma, 0.6) ** 2 + 1.0 / 12.0)


RING_BLEND_SIGMAS = 4.0  # a ring PSF's maxima on opposite sides lie ~2.7 sigma apart: one star, not a blend


def blend_separation_px(sigma: float, rings: bool = False) -> float:
    """
    Smallest separation [px] of a second star split from a spot.

    2 PSF sigmas (at least 2 px); RING_BLEND_SIGMAS for ring stars (psf.estimate.PsfEstimate.annular).
    """
    return max(2.0, (RING_BLEND_SIGMAS if rings else 2.0) * sigma)


def hot_pixel_ratio(config: CentroidConfig, sigma: float) -> float:
    """
    Peak-to-brightest-neighbour ratio above which a pixel is a defect, not starlight (twice what the PSF allows).

    inf (no cleaning) without a PSF.
    """
    return 2.0 * star_peak_to_neighbour_ratio(sigma) if config.psf_sigma_px > 0 else np.inf


def peak_fraction_limit(config: CentroidConfig, sigma: float) -> float:
    """
    Largest share of a spot's flux its brightest pixel may hold [-].

    max_peak_fraction, or for a PSF so narrow that a star centred on a pixel puts more than
    that in it, 1.3x that share (at most 0.95: a hot pixel holds all of it).
    """
    centred = float(erf(0.5 / (np.sqrt(2.0) * max(sigma, 1e-3))) ** 2)
    return max(config.max_peak_fraction, min(0.95, 1.3 * centred))
