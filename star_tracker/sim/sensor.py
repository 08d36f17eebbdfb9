"""The simulated sensor: optics radiometry (star magnitude to photo-electrons), detector
(dark current and its temperature law, fixed-pattern non-uniformities, hot pixels, cosmic rays,
read noise, gain, full well, ADC) and shutter timing, as one validated parameter record that
sim.render.StarFieldRenderer draws frames with. SI units; equations in docs/SIMULATOR.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SensorModel:
    """Optics radiometry, detector and shutter parameters (SI units).

    Radiometry: a star of instrument magnitude m = Hp + color_coefficient (B-V) delivers
    photon_flux_hp0 10^(-0.4 m) [photons/s/m^2] to an aperture of diameter
    aperture_diameter_m [m]; optical_transmission and quantum_efficiency [-] turn photons into
    photo-electrons. exposure_s [s]; psf_sigma_px: Gaussian PSF (defocus) 1-sigma [px].
    Background: sky/zodiacal background_e_per_px_s [e-/px/s] plus a linear stray-light
    gradient [e-/px/s per px] in x and y about the image centre; vignetting_at_corner: fraction
    of light lost at the image corner (quadratic in radius).
    Detector: pixel_pitch_m [m]; dark current dark_e_per_px_s at dark_reference_k [K],
    doubling every dark_doubling_k [K], at temperature_k [K]; dsnu_fraction: per-pixel dark
    non-uniformity (lognormal sigma) [-]; prnu_fraction: per-pixel response non-uniformity
    1-sigma [-]; hot_pixel_fraction of pixels have hot_pixel_dark_factor times the dark
    current; cosmic rays arrive at cosmic_ray_rate_per_cm2_s [1/cm^2/s] depositing on average
    cosmic_ray_electrons [e-] along a short track; read_noise_e [e-]; gain_e_per_adu
    [e-/ADU]; bias_adu [ADU]; full_well_e [e-] (clipped, no blooming); adc_bits.
    Shutter: rolling_shutter_row_time_s [s] (0 = global shutter; row r's exposure is
    delayed by (r - (H-1)/2) times it); frame_transfer_time_s [s] (0 = none) smears every
    column during transfer. noise: False renders expected values (no shot/read noise).
    """

    aperture_diameter_m: float = 0.03
    optical_transmission: float = 0.8
    quantum_efficiency: float = 0.6
    photon_flux_hp0: float = 2.0e10
    color_coefficient: float = 0.0
    exposure_s: float = 0.1
    psf_sigma_px: float = 1.0
    background_e_per_px_s: float = 400.0
    stray_light_gradient_e_per_px2_s: tuple[float, float] = (0.0, 0.0)
    vignetting_at_corner: float = 0.0
    pixel_pitch_m: float = 13e-6
    dark_e_per_px_s: float = 20.0
    dark_reference_k: float = 293.15
    dark_doubling_k: float = 6.0
    temperature_k: float = 293.15
    dsnu_fraction: float = 0.0
    prnu_fraction: float = 0.0
    hot_pixel_fraction: float = 0.0
    hot_pixel_dark_factor: float = 200.0
    cosmic_ray_rate_per_cm2_s: float = 0.0
    cosmic_ray_electrons: float = 3000.0
    read_noise_e: float = 8.0
    gain_e_per_adu: float = 1.0
    bias_adu: float = 100.0
    full_well_e: float = 60000.0
    adc_bits: int = 16
    rolling_shutter_row_time_s: float = 0.0
    frame_transfer_time_s: float = 0.0
    noise: bool = True

    def __post_init__(self) -> None:
        positive = ("aperture_diameter_m", "photon_flux_hp0", "exposure_s", "psf_sigma_px", "pixel_pitch_m",
                    "dark_reference_k", "dark_doubling_k", "temperature_k", "gain_e_per_adu", "full_well_e")
        fractions = ("optical_transmission", "quantum_efficiency")
        non_negative = ("background_e_per_px_s", "dark_e_per_px_s", "dsnu_fraction", "prnu_fraction",
                        "hot_pixel_dark_factor", "cosmic_ray_rate_per_cm2_s", "cosmic_ray_electrons", "read_noise_e",
                        "bias_adu", "rolling_shutter_row_time_s", "frame_transfer_time_s")
        bad = [f"{n}={getattr(self, n)} must be > 0" for n in positive if not (np.isfinite(getattr(self, n)) and getattr(self, n) > 0)]
        bad += [f"{n}={getattr(self, n)} must be in (0, 1]" for n in fractions if not (0 < getattr(self, n) <= 1)]
        bad += [f"{n}={getattr(self, n)} must be >= 0" for n in non_negative if not (np.isfinite(getattr(self, n)) and getattr(self, n) >= 0)]
        if not (0 <= self.vignetting_at_corner < 1):
            bad.append(f"vignetting_at_corner={self.vignetting_at_corner} must be in [0, 1)")
        if not (0 <= self.hot_pixel_fraction <= 0.1):
            bad.append(f"hot_pixel_fraction={self.hot_pixel_fraction} must be in [0, 0.1]")
        if not (8 <= int(self.adc_bits) <= 16):
            bad.append(f"adc_bits={self.adc_bits} must be in [8, 16]")
        if not np.isfinite(self.color_coefficient):
            bad.append("color_coefficient must be finite")
        if len(self.stray_light_gradient_e_per_px2_s) != 2 or not np.all(np.isfinite(self.stray_light_gradient_e_per_px2_s)):
            bad.append("stray_light_gradient_e_per_px2_s must be 2 finite values")
        if bad:
            raise ValueError("invalid sensor parameters: " + "; ".join(bad))

    @property
    def zero_point_e_per_s(self) -> float:
        """Photo-electrons per second from an instrument-magnitude-0 star."""
        area = np.pi * (0.5 * self.aperture_diameter_m) ** 2
        return self.photon_flux_hp0 * area * self.optical_transmission * self.quantum_efficiency

    def star_electrons(self, hp: np.ndarray, b_v: np.ndarray | float = 0.0) -> np.ndarray:
        """Expected photo-electrons per exposure (before vignetting) of stars of Hp and B-V."""
        magnitude = np.asarray(hp) + self.color_coefficient * np.asarray(b_v)
        return self.zero_point_e_per_s * self.exposure_s * 10.0 ** (-0.4 * magnitude)

    @property
    def dark_e_per_px_s_at_temperature(self) -> float:
        return self.dark_e_per_px_s * 2.0 ** ((self.temperature_k - self.dark_reference_k) / self.dark_doubling_k)

    @property
    def max_adu(self) -> int:
        return (1 << int(self.adc_bits)) - 1
