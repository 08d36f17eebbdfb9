"""camera_simulator's start-up parameters, declared with descriptors and ranges and gathered
into the models they configure: camera, sensor, false objects, sky and attitude motion.
Declared in a fixed order (the first bad value is the one reported)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..models.attitude import quaternion_to_matrix, radec_roll_to_matrix
from ..models.camera import CameraModel
from ..sim.motion import motion_from_parameters
from ..sim.render import FalseObjectModel
from ..sim.sensor import SensorModel

Declare = Callable[..., Any]  # declare(node, ...) bound to the node: (name, default, description, low, high) -> value


def declare_camera(p: Declare) -> tuple[CameraModel, float]:
    """The image size and optics: (the camera model, the horizontal field of view [deg])."""
    width = p("image.width", 1024, "image width [px]", 16, 8192)
    height = p("image.height", 1024, "image height [px]", 16, 8192)
    fov_x_deg = p("optics.fov_x_deg", 15.0, "horizontal field of view [deg]", 0.5, 120.0)
    distortion = p("optics.distortion", [0.0, 0.0, 0.0, 0.0, 0.0],
                   "Brown-Conrady plumb_bob k1, k2, p1, p2, k3 (published in camera_info)")
    # A distortion of other than 5 values is refused here, by the camera model.
    return CameraModel.from_fov(width, height, np.radians(fov_x_deg), tuple(distortion)), fov_x_deg


def declare_sensor(p: Declare) -> SensorModel:
    """Radiometry, detector and shutter parameters."""
    return SensorModel(
        aperture_diameter_m=p("optics.aperture_diameter_m", 0.03, "entrance pupil diameter [m]", 1e-4, 10.0),
        optical_transmission=p("optics.transmission", 0.8, "optical transmission [-]", 1e-3, 1.0),
        psf_sigma_px=p("optics.psf_sigma_px", 1.0, "Gaussian PSF (defocus) 1-sigma [px]", 0.1, 20.0),
        vignetting_at_corner=p("optics.vignetting_at_corner", 0.1, "light lost at the image corner [-]", 0.0, 0.99),
        photon_flux_hp0=p("sky.photon_flux_hp0", 2.0e10, "photons/s/m^2 in the sensor band from an Hp=0 star", 1e-6, 1e14),
        color_coefficient=p("sky.color_coefficient", 0.0, "instrument magnitude = Hp + c (B-V) [-]", -5.0, 5.0),
        background_e_per_px_s=p("sky.background_e_per_px_s", 400.0, "sky + zodiacal background [e-/px/s]", 0.0, 1e9),
        stray_light_gradient_e_per_px2_s=tuple(p("sky.stray_light_gradient_e_per_px2_s", [0.0, 0.0],
                                                 "linear stray-light gradient in x, y [e-/px/s per px]")),
        exposure_s=p("sensor.exposure_s", 0.1, "exposure time [s]", 1e-6, 10.0),
        pixel_pitch_m=p("sensor.pixel_pitch_m", 13e-6, "pixel pitch [m]", 1e-7, 1e-3),
        quantum_efficiency=p("sensor.quantum_efficiency", 0.6, "quantum efficiency [-]", 1e-3, 1.0),
        dark_e_per_px_s=p("sensor.dark_e_per_px_s", 20.0, "dark current at dark_reference_k [e-/px/s]", 0.0, 1e9),
        dark_reference_k=p("sensor.dark_reference_k", 293.15, "reference temperature of dark_e_per_px_s [K]", 1.0, 500.0),
        dark_doubling_k=p("sensor.dark_doubling_k", 6.0, "dark current doubles every this many kelvin [K]", 0.1, 100.0),
        temperature_k=p("sensor.temperature_k", 293.15, "detector temperature [K]", 1.0, 500.0),
        dsnu_fraction=p("sensor.dsnu_fraction", 0.1, "dark signal non-uniformity, lognormal sigma [-]", 0.0, 5.0),
        prnu_fraction=p("sensor.prnu_fraction", 0.01, "photo-response non-uniformity 1-sigma [-]", 0.0, 0.5),
        hot_pixel_fraction=p("sensor.hot_pixel_fraction", 2e-5, "fraction of hot pixels [-]", 0.0, 0.1),
        hot_pixel_dark_factor=p("sensor.hot_pixel_dark_factor", 200.0, "hot pixel dark current multiple [-]", 0.0, 1e6),
        cosmic_ray_rate_per_cm2_s=p("sensor.cosmic_ray_rate_per_cm2_s", 5.0, "cosmic-ray hit rate [1/cm^2/s]", 0.0, 1e6),
        cosmic_ray_electrons=p("sensor.cosmic_ray_electrons", 3000.0, "mean charge of a hit [e-]", 0.0, 1e9),
        read_noise_e=p("sensor.read_noise_e", 8.0, "read noise 1-sigma [e-]", 0.0, 1e4),
        gain_e_per_adu=p("sensor.gain_e_per_adu", 1.0, "conversion gain [e-/ADU]", 1e-3, 1e4),
        bias_adu=p("sensor.bias_adu", 100.0, "bias offset [ADU]", 0.0, 65535.0),
        full_well_e=p("sensor.full_well_e", 60000.0, "full-well capacity [e-]", 1.0, 1e9),
        adc_bits=p("sensor.adc_bits", 16, "ADC bit depth", 8, 16),
        rolling_shutter_row_time_s=p("sensor.rolling_shutter_row_time_s", 0.0,
                                     "row readout delay of a rolling shutter; 0 = global shutter [s]", 0.0, 1e-2),
        frame_transfer_time_s=p("sensor.frame_transfer_time_s", 0.0, "frame-transfer time; 0 = none [s]", 0.0, 1.0),
        noise=p("sensor.noise", True, "shot and read noise on (false renders expected values)"),
    )


def declare_false_objects(p: Declare) -> FalseObjectModel:
    """Non-catalog objects in view: planets (points) and debris (streaks)."""
    return FalseObjectModel(
        planets_per_frame=p("false_objects.planets_per_frame", 0, "bright non-catalog points per frame", 0, 100),
        planet_magnitude_range=tuple(p("false_objects.planet_magnitude_range", [-1.0, 2.0], "instrument magnitude range")),
        debris_per_frame=p("false_objects.debris_per_frame", 0, "moving debris streaks per frame", 0, 100),
        debris_magnitude_range=tuple(p("false_objects.debris_magnitude_range", [3.0, 6.0], "instrument magnitude range")),
        debris_speed_px_s=tuple(p("false_objects.debris_speed_px_s", [100.0, 1000.0], "image speed range [px/s]")),
    )


@dataclass(frozen=True)
class SkySetup:
    """What the sky holds and how it looks from the spacecraft."""

    magnitude_limit: float  # faintest star rendered [Hp mag]
    epoch_jyear: float  # catalog epoch [Julian year]; 0 = the clock's date
    observer_velocity_m_s: list  # spacecraft velocity in ICRS, for aberration [m/s]
    fixed_pattern_seed: int  # seed of PRNU, DSNU and hot pixels


def declare_sky(p: Declare) -> SkySetup:
    return SkySetup(
        magnitude_limit=p("sky.magnitude_limit", 7.5, "faintest star rendered [Hp mag]", -2.0, 12.0),
        epoch_jyear=p("sky.epoch_jyear", 0.0, "catalog epoch [Julian year]; 0 = the clock's date", 0.0, 2200.0),
        observer_velocity_m_s=p("sky.observer_velocity_m_s", [0.0, 0.0, 0.0],
                                "spacecraft velocity in ICRS for stellar aberration [m/s] (Earth orbit ~ 30 km/s)"),
        fixed_pattern_seed=p("fixed_pattern_seed", 0, "seed of PRNU, DSNU and hot pixels", 0, 2**31 - 1))


@dataclass(frozen=True)
class AttitudeSetup:
    """The motion the simulated camera follows."""

    profile: str  # fixed, constant_rate, slew, tumble, jitter or external
    initial_rotation: np.ndarray  # sensor -> ICRS rotation matrix at the first exposure
    motion_kwargs: dict  # profile -> keyword arguments of motion_from_parameters (SI units, radians)


def declare_motion_kwargs(p: Declare) -> dict:
    """Every profile's motion parameters (all declared, whichever profile runs), in radians."""
    deg = np.radians
    body_rate = deg(p("attitude.body_rate_deg_s", [0.0, 0.0, 0.0],
                      "constant body rate in the sensor frame x, y, z (constant_rate, jitter base) [deg/s]"))
    return {
        "fixed": {},
        "constant_rate": {"body_rate_rad_s": body_rate},
        "slew": {"axis": p("attitude.slew.axis", [1.0, 0.0, 0.0], "slew axis in the sensor frame"),
                 "angle_rad": deg(p("attitude.slew.angle_deg", 10.0, "slew angle [deg]", -3600.0, 3600.0)),
                 "max_rate_rad_s": deg(p("attitude.slew.max_rate_deg_s", 2.0, "coast rate [deg/s]", 1e-6, 90.0)),
                 "accel_rad_s2": deg(p("attitude.slew.accel_deg_s2", 0.5, "acceleration [deg/s^2]", 1e-6, 1000.0)),
                 "t_start": p("attitude.slew.start_s", 2.0, "slew start after the first exposure [s]", 0.0, 1e6)},
        "tumble": {"initial_rate_rad_s": deg(p("attitude.tumble.initial_rate_deg_s", [0.5, 0.2, 1.0],
                                               "initial body rate [deg/s]")),
                   "inertia_kg_m2": p("attitude.tumble.inertia_kg_m2", [10.0, 12.0, 8.0],
                                      "principal moments about the sensor x, y, z axes [kg m^2]")},
        "jitter": {"body_rate_rad_s": body_rate,
                   "amplitudes_rad": p("attitude.jitter.amplitudes_rad", [2e-5, 2e-5, 1e-5],
                                       "sinusoid amplitudes x, y, z per term, flat (3N) [rad]"),
                   "frequencies_hz": p("attitude.jitter.frequencies_hz", [7.0], "sinusoid frequencies (N) [Hz]"),
                   "phases_rad": p("attitude.jitter.phases_rad", [0.0], "phases: 1, N or 3N values [rad]")},
    }


def declare_attitude(p: Declare) -> AttitudeSetup:
    """The initial attitude (a quaternion, else RA/Dec/roll) and the motion profile, checked:
    a bad profile fails at startup, not at the first frame."""
    quaternion = p("attitude.quaternion", [0.0, 0.0, 0.0, 0.0],
                   "initial sensor->ICRS quaternion x, y, z, w; all zero = use RA/Dec/roll")
    ra = np.radians(p("attitude.ra_deg", 80.0, "initial boresight right ascension [deg]", -360.0, 360.0))
    dec = np.radians(p("attitude.dec_deg", 20.0, "initial boresight declination [deg]", -90.0, 90.0))
    roll = np.radians(p("attitude.roll_deg", 0.0, "initial roll about the boresight [deg]", -360.0, 360.0))
    profile = p("attitude.profile", "constant_rate",
                "motion: fixed, constant_rate, slew, tumble, jitter, or external (follow truth_in/ topics)")
    motion_kwargs = declare_motion_kwargs(p)
    if profile not in (*motion_kwargs, "external"):
        raise ValueError(f"attitude.profile={profile!r}: expected one of {sorted([*motion_kwargs, 'external'])}")
    if len(quaternion) != 4:  # (the camera model has refused a distortion of other than 5 values)
        raise ValueError("optics.distortion needs 5 values, attitude.quaternion 4")
    if not np.all(np.isfinite(quaternion)):  # NaN would fall through to RA/Dec/roll unnoticed
        raise ValueError(f"attitude.quaternion={list(quaternion)} must be finite")
    if np.linalg.norm(quaternion) > 0:
        initial = quaternion_to_matrix(np.asarray(quaternion, dtype=float))
    else:
        initial = radec_roll_to_matrix(ra, dec, roll)
    if profile != "external":
        motion_from_parameters(profile, initial, **motion_kwargs[profile])
    return AttitudeSetup(profile, initial, motion_kwargs)
