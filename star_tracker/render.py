"""Star-field rendering: radiometry, pixel-integrated Gaussian PSF, motion smear, sensor noise.

Units: electrons [e-] inside, ADU on output; angles in radians; times in seconds.
The frame's truth (attitude at mid-exposure, which star landed where) comes with the image.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import erf

from .camera import CameraModel
from .catalog import StarCatalog


@dataclass(frozen=True)
class SensorModel:
    """Radiometry and detector parameters.

    zero_point_e_per_s: photo-electrons per second collected from an Hp = 0 star
        (aperture area x optical transmission x QE x photon flux of a mag-0 star);
    exposure_s: integration time [s]; psf_sigma_px: Gaussian PSF 1-sigma [px];
    background_e_per_px_s: sky + stray light [e-/px/s]; dark_e_per_px_s: dark current [e-/px/s];
    read_noise_e: read noise 1-sigma [e-]; gain_e_per_adu: [e-/ADU]; bias_adu: offset [ADU];
    full_well_e: saturation level [e-]; adc_bits: ADC depth.
    """

    zero_point_e_per_s: float = 1.0e7
    exposure_s: float = 0.1
    psf_sigma_px: float = 1.0
    background_e_per_px_s: float = 400.0
    dark_e_per_px_s: float = 20.0
    read_noise_e: float = 8.0
    gain_e_per_adu: float = 1.0
    bias_adu: float = 100.0
    full_well_e: float = 60000.0
    adc_bits: int = 16

    def __post_init__(self) -> None:
        checks = {
            "zero_point_e_per_s": self.zero_point_e_per_s > 0,
            "exposure_s": self.exposure_s > 0,
            "psf_sigma_px": self.psf_sigma_px > 0,
            "background_e_per_px_s": self.background_e_per_px_s >= 0,
            "dark_e_per_px_s": self.dark_e_per_px_s >= 0,
            "read_noise_e": self.read_noise_e >= 0,
            "gain_e_per_adu": self.gain_e_per_adu > 0,
            "bias_adu": self.bias_adu >= 0,
            "full_well_e": self.full_well_e > 0,
            "adc_bits": 8 <= int(self.adc_bits) <= 16,
        }
        bad = [name for name, ok in checks.items() if not (ok and np.isfinite(float(getattr(self, name))))]
        if bad:
            raise ValueError("invalid sensor parameters: " + ", ".join(f"{n}={getattr(self, n)}" for n in bad))

    def star_electrons(self, magnitude: np.ndarray) -> np.ndarray:
        """Expected photo-electrons per exposure from a star of Hp `magnitude`."""
        return self.zero_point_e_per_s * self.exposure_s * 10.0 ** (-0.4 * np.asarray(magnitude))

    @property
    def background_e(self) -> float:
        """Expected sky + dark electrons per pixel per exposure."""
        return (self.background_e_per_px_s + self.dark_e_per_px_s) * self.exposure_s

    @property
    def max_adu(self) -> int:
        return (1 << int(self.adc_bits)) - 1


@dataclass(frozen=True)
class FrameTruth:
    """What the simulator used for one frame.

    stamp_s: mid-exposure time [s]; rotation: sensor -> ICRS at mid-exposure;
    body_rate: [rad/s] in the sensor frame; hip, x, y: stars rendered and their pixel position
    at mid-exposure [px]; electrons: expected signal of each [e-].
    """

    stamp_s: float
    rotation: np.ndarray
    body_rate: np.ndarray
    hip: np.ndarray
    x: np.ndarray
    y: np.ndarray
    electrons: np.ndarray


@dataclass(frozen=True)
class RenderedFrame:
    image: np.ndarray  # uint16 (height, width) [ADU]
    truth: FrameTruth
    substeps: int = field(default=1)


class StarFieldRenderer:
    """Renders frames for a camera, sensor and catalog (stars brighter than a render limit)."""

    def __init__(self, camera: CameraModel, sensor: SensorModel, catalog: StarCatalog,
                 magnitude_limit: float = 7.5, max_substep_px: float = 0.5):
        self.camera = camera
        self.sensor = sensor
        self.catalog = catalog.brighter_than(magnitude_limit)
        self.star_vectors = self.catalog.unit_vectors()
        self.star_electrons = sensor.star_electrons(self.catalog.hp)
        self.max_substep_px = max_substep_px
        self._half = int(np.ceil(4.0 * sensor.psf_sigma_px)) + 1
        self._cos_search = np.cos(min(camera.half_diagonal_fov_rad + 0.02, np.pi / 2))

    def render(self, rotations_over_exposure, stamp_s: float, body_rate: np.ndarray,
               rng: np.random.Generator) -> RenderedFrame:
        """rotations_over_exposure(times) -> (K, 3, 3) sensor->ICRS rotations. The exposure spans
        stamp_s +/- exposure/2; it is integrated in K sub-steps so that no star moves more than
        `max_substep_px` pixels between steps."""
        cam, sensor = self.camera, self.sensor
        exposure = sensor.exposure_s
        rot_mid = rotations_over_exposure(np.array([stamp_s]))[0]
        boresight = rot_mid[:, 2]
        near = np.flatnonzero(self.star_vectors @ boresight > self._cos_search)
        vectors = self.star_vectors[near]
        # Upper bound of image motion: |omega| T times the focal length at the field edge.
        edge_gain = 1.0 / np.cos(cam.half_diagonal_fov_rad) ** 2
        smear_px = float(np.linalg.norm(body_rate)) * exposure * max(cam.fx, cam.fy) * edge_gain
        substeps = int(min(400, max(1, np.ceil(smear_px / self.max_substep_px))))
        times = stamp_s + ((np.arange(substeps) + 0.5) / substeps - 0.5) * exposure
        rotations = rotations_over_exposure(times)
        # Sensor-frame rays of each star at each sub-step: v_sensor = R^T v_icrs.
        rays = np.einsum("kji,nj->kni", rotations, vectors)
        u, v, in_front = cam.project(rays)
        electrons = np.broadcast_to(self.star_electrons[near] / substeps, u.shape)

        signal = np.zeros(cam.height * cam.width)
        visible = in_front & cam.in_image(u, v, margin=-self._half)
        self._accumulate(signal, u[visible], v[visible], electrons[visible])
        signal = signal.reshape(cam.height, cam.width)

        image = self._add_noise(signal, rng)

        u_mid, v_mid, front_mid = cam.project(vectors @ rot_mid)
        on_chip = front_mid & cam.in_image(u_mid, v_mid)
        truth = FrameTruth(
            stamp_s=stamp_s, rotation=rot_mid, body_rate=np.asarray(body_rate, float),
            hip=self.catalog.hip[near][on_chip], x=u_mid[on_chip], y=v_mid[on_chip],
            electrons=self.star_electrons[near][on_chip])
        return RenderedFrame(image=image, truth=truth, substeps=substeps)

    def _accumulate(self, signal: np.ndarray, u: np.ndarray, v: np.ndarray, electrons: np.ndarray) -> None:
        """Add pixel-integrated Gaussian spots: each pixel gets the PSF integral over its area."""
        if u.size == 0:
            return
        cam, sigma, half = self.camera, self.sensor.psf_sigma_px, self._half
        offsets = np.arange(-half, half + 1)
        col0 = np.rint(u).astype(np.int64)
        row0 = np.rint(v).astype(np.int64)
        cols = col0[:, None] + offsets[None, :]
        rows = row0[:, None] + offsets[None, :]
        scale = 1.0 / (np.sqrt(2.0) * sigma)
        # 1-D pixel integrals of the Gaussian; the PSF is separable.
        px = 0.5 * (erf((cols + 0.5 - u[:, None]) * scale) - erf((cols - 0.5 - u[:, None]) * scale))
        py = 0.5 * (erf((rows + 0.5 - v[:, None]) * scale) - erf((rows - 0.5 - v[:, None]) * scale))
        weights = electrons[:, None, None] * py[:, :, None] * px[:, None, :]
        rr = np.broadcast_to(rows[:, :, None], weights.shape)
        cc = np.broadcast_to(cols[:, None, :], weights.shape)
        inside = (rr >= 0) & (rr < cam.height) & (cc >= 0) & (cc < cam.width)
        flat = rr[inside] * cam.width + cc[inside]
        signal += np.bincount(flat, weights=weights[inside], minlength=signal.size)

    def _add_noise(self, signal: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Shot noise, read noise, gain, bias, full well and ADC clipping.

        Pixels with star signal get exact Poisson draws of (signal + background). Elsewhere
        the background shot noise and read noise are drawn together as one Gaussian of the
        exact variance (background + read^2): the background is tens of electrons, where the
        Poisson skew is negligible, and this keeps a 1 Mpx frame cheap.
        """
        sensor = self.sensor
        background = sensor.background_e
        sigma_flat = np.sqrt(background + sensor.read_noise_e**2)
        electrons = background + sigma_flat * rng.standard_normal(signal.shape, dtype=np.float32)
        lit = signal > 0.05
        lam = signal[lit] + background
        electrons[lit] = rng.poisson(lam) + sensor.read_noise_e * rng.standard_normal(lam.size)
        np.minimum(electrons, sensor.full_well_e, out=electrons)
        adu = electrons / sensor.gain_e_per_adu + sensor.bias_adu
        np.clip(adu, 0, sensor.max_adu, out=adu)
        return np.rint(adu).astype(np.uint16)
