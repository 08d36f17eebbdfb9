# SPDX-License-Identifier: Apache-2.0
"""
The simulated sensor.

Optics radiometry (star magnitude to photo-electrons), detector (dark current and its
temperature law, fixed-pattern non-uniformities, hot pixels, cosmic rays, read noise, gain,
full well, ADC) and shutter timing, as one validated parameter record that
sim.render.StarFieldRenderer draws frames with. SI units; equations in docs/SIMULATOR.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..parameter_spec import parameter, range_problems


@dataclass(frozen=True)
class SensorModel:
    """
    Optics radiometry, detector and shutter parameters (SI units).

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
    Each field's default, unit and accepted range: its `parameter(...)` (parameter_spec.py).
    """

    aperture_diameter_m: float = parameter(0.03, "entrance pupil diameter", "m", 1e-4, 10.0)
    optical_transmission: float = parameter(0.8, "optical transmission", "-", 1e-3, 1.0)
    quantum_efficiency: float = parameter(0.6, "quantum efficiency", "-", 1e-3, 1.0)
    photon_flux_hp0: float = parameter(2.0e10, "photons in the sensor band from an Hp = 0 star", "photons/s/m^2",
                                       1e-6, 1e14)
    color_coefficient: float = parameter(0.0, "instrument magnitude = Hp + c (B-V)", "-", -5.0, 5.0)
    exposure_s: float = parameter(0.1, "exposure time", "s", 1e-6, 10.0)
    psf_sigma_px: float = parameter(1.0, "Gaussian PSF (defocus) 1-sigma", "px", 0.1, 20.0)
    background_e_per_px_s: float = parameter(400.0, "sky + zodiacal background", "e-/px/s", 0.0, 1e9)
    stray_light_gradient_e_per_px2_s: tuple[float, float] = parameter(
        (0.0, 0.0), "linear stray-light gradient in x, y about the image centre", "e-/px/s per px")
    vignetting_at_corner: float = parameter(0.0, "light lost at the image corner (quadratic in radius)", "-", 0.0,
                                            0.99)
    pixel_pitch_m: float = parameter(13e-6, "pixel pitch", "m", 1e-7, 1e-3)
    dark_e_per_px_s: float = parameter(20.0, "dark current at dark_reference_k", "e-/px/s", 0.0, 1e9)
    dark_reference_k: float = parameter(293.15, "reference temperature of dark_e_per_px_s", "K", 1.0, 500.0)
    dark_doubling_k: float = parameter(6.0, "dark current doubles every this many kelvin", "K", 0.1, 100.0)
    temperature_k: float = parameter(293.15, "detector temperature", "K", 1.0, 500.0)
    dsnu_fraction: float = parameter(0.0, "dark signal non-uniformity, lognormal sigma", "-", 0.0, 5.0)
    prnu_fraction: float = parameter(0.0, "photo-response non-uniformity 1-sigma", "-", 0.0, 0.5)
    hot_pixel_fraction: float = parameter(0.0, "fraction of hot pixels", "-", 0.0, 0.1)
    hot_pixel_dark_factor: float = parameter(200.0, "hot pixel dark current multiple", "-", 0.0, 1e12)
    cosmic_ray_rate_per_cm2_s: float = parameter(0.0, "cosmic-ray hit rate", "1/cm^2/s", 0.0, 1e6)
    cosmic_ray_electrons: float = parameter(3000.0, "mean charge of a hit", "e-", 0.0, 1e9)
    read_noise_e: float = parameter(8.0, "read noise 1-sigma", "e-", 0.0, 1e4)
    gain_e_per_adu: float = parameter(1.0, "conversion gain", "e-/ADU", 1e-3, 1e4)
    bias_adu: float = parameter(100.0, "bias offset", "ADU", 0.0, 65535.0)
    full_well_e: float = parameter(60000.0, "full-well capacity (clipped, no blooming)", "e-", 1.0, 1e9)
    adc_bits: int = parameter(16, "ADC bit depth", "", 8, 16)
    rolling_shutter_row_time_s: float = parameter(0.0, "row readout delay of a rolling shutter; 0 = global shutter",
                                                  "s", 0.0, 1e-2)
    frame_transfer_time_s: float = parameter(0.0, "frame-transfer time; 0 = no frame-transfer smear", "s", 0.0, 1.0)
    noise: bool = parameter(True, "shot and read noise on (false renders expected values)")

    def __post_init__(self) -> None:
        bad = range_problems(self)
        gradient = self.stray_light_gradient_e_per_px2_s
        if len(gradient) != 2 or not np.all(np.isfinite(gradient)):
            bad.append("stray_light_gradient_e_per_px2_s must be 2 finite values")
        if bad:
            raise ValueError("invalid sensor parameters: " + "; ".join(bad))

    @property
    def zero_point_e_per_s(self) -> float:
        """Photo-electrons per second from an instrument-magnitude-0 star."""
        area = np.pi * (0.5 * self.aperture_diameter_m) ** 2
        return self.photon_flux_hp0 * area * self.optical_transmission * self.quantum_efficiency

    def star_electrons(self, hp: np.ndarray, b_v: np.ndarray | float = 0.0) -> np.ndarray:
        """Return the expected photo-electrons per exposure (before vignetting) of stars of Hp and B-V."""
        magnitude = np.asarray(hp) + self.color_coefficient * np.asarray(b_v)
        return self.zero_point_e_per_s * self.exposure_s * 10.0 ** (-0.4 * magnitude)

    @property
    def dark_e_per_px_s_at_temperature(self) -> float:
        return self.dark_e_per_px_s * 2.0 ** ((self.temperature_k - self.dark_reference_k) / self.dark_doubling_k)

    @property
    def max_adu(self) -> int:
        return (1 << int(self.adc_bits)) - 1
