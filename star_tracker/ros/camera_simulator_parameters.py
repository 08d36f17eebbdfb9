# SPDX-License-Identifier: Apache-2.0
"""
camera_simulator's parameters, each declared once (ROS-free).

The SensorModel and FalseObjectModel fields (their spec is the dataclass field metadata,
sim/sensor.py, sim/render.py) under the node's names with the simulated camera's defaults, and the
node's own; in the order the node declares them (the first bad value is the one reported) and
config/star_tracker.yaml lists them. The models the node runs are built from the declared values
here.

Dynamic (`ros2 param set` while running): the sensor settings a camera driver changes between
frames (exposure, gain, read noise, bias, detector temperature); the renderer is rebuilt with
them for the next frame. The rest (image size, optics, sky, motion) is read-only.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..models.attitude import quaternion_to_matrix, radec_roll_to_matrix
from ..models.camera import CameraModel
from ..parameter_spec import ParameterSpec, field_specs, field_values
from .autostart_parameter import AUTOSTART
from ..sim.motion import motion_from_parameters
from ..sim.render import FalseObjectModel
from ..sim.sensor import SensorModel
from .camera_simulator_orbit import ORBIT_PARAMETERS, ORBIT_PROFILES

Declare = Callable[..., Any]  # (name, default, description, low, high) -> value: a parameter source

# The simulated camera: SensorModel's defaults with a realistic detector's defects.
SIMULATED_SENSOR = SensorModel(vignetting_at_corner=0.1, dsnu_fraction=0.1, prnu_fraction=0.01,
                               hot_pixel_fraction=2e-5, cosmic_ray_rate_per_cm2_s=5.0)
# Node parameter -> SensorModel field, where the name is not "sensor." + the field.
SENSOR_NAMES = {"aperture_diameter_m": "optics.aperture_diameter_m", "optical_transmission": "optics.transmission",
                "psf_sigma_px": "optics.psf_sigma_px", "vignetting_at_corner": "optics.vignetting_at_corner",
                "photon_flux_hp0": "sky.photon_flux_hp0", "color_coefficient": "sky.color_coefficient",
                "background_e_per_px_s": "sky.background_e_per_px_s",
                "stray_light_gradient_e_per_px2_s": "sky.stray_light_gradient_e_per_px2_s"}
# What a camera driver changes between frames: rebuilt into the renderer for the next frame.
SENSOR_RUNTIME = ("exposure_s", "gain_e_per_adu", "read_noise_e", "bias_adu", "temperature_k")
SENSOR_PARAMETERS = field_specs(SensorModel, prefix="sensor.", names=SENSOR_NAMES, defaults=SIMULATED_SENSOR,
                                dynamic=SENSOR_RUNTIME)
FALSE_OBJECT_PARAMETERS = field_specs(FalseObjectModel, prefix="false_objects.")
_SENSOR = {spec.name: spec for spec in SENSOR_PARAMETERS}


def _sensor(name: str) -> ParameterSpec:
    return _SENSOR[name]


OUTPUT_PARAMETERS = [
    ParameterSpec("rate_hz", 10.0, "frame rate", "Hz", 0.01, 1000.0),
    ParameterSpec("max_frames", 0, "stop publishing after this many frames; 0 = never", "", 0, 10**9),
    ParameterSpec("start_delay_s", 0.0, "wait before the first exposure", "s", 0.0, 3600.0),
    ParameterSpec("sync_exposures", False, "put every frame's stamp (mid-exposure) on a multiple of the frame "
                  "period of the node's clock (UNIX time): cameras with the same rate_hz and exposure expose together, "
                  "as heads on one sync pulse"),
    ParameterSpec("wait_for_subscribers", False, "begin exposures only once image_raw, camera_info and "
                  "truth/attitude each have a subscriber (then start_delay_s more): no frame lost to DDS discovery"),
    ParameterSpec("max_backlog_frames", 5, "frames delivered late before older ones are skipped (counted)", "", 0,
                  1000),
    ParameterSpec("frame_id", "star_tracker_optical", "frame_id of image_raw, camera_info, truth/objects and "
                  "truth/angular_velocity"),
    ParameterSpec("seed", 0, "noise seed: frame k's noise comes from the stream (seed, k)", "", 0, 2**31 - 1),
    ParameterSpec("fixed_pattern_seed", 0, "seed of PRNU, DSNU and hot pixels", "", 0, 2**31 - 1),
]
CAMERA_PARAMETERS = [
    ParameterSpec("image.width", 1024, "image width", "px", 16, 8192),
    ParameterSpec("image.height", 1024, "image height", "px", 16, 8192),
    ParameterSpec("optics.fov_x_deg", 15.0, "horizontal field of view", "deg", 0.5, 120.0),
    _sensor("optics.psf_sigma_px"),
    ParameterSpec("optics.distortion", (0.0, 0.0, 0.0, 0.0, 0.0), "Brown-Conrady plumb_bob k1, k2, p1, p2, k3 "
                  "(published in camera_info)"),
    _sensor("optics.aperture_diameter_m"),
    _sensor("optics.transmission"),
    _sensor("optics.vignetting_at_corner"),
]
READOUT_PARAMETER = ParameterSpec("sensor.readout_s", 0.0, "readout: a frame is published this long after its "
                                  "exposure (the last row's, under a rolling shutter) and frame transfer ended; "
                                  "0 = at once", "s", 0.0, 10.0)
SKY_PARAMETERS = [
    ParameterSpec("sky.magnitude_limit", 7.5, "faintest star rendered", "Hp mag", -2.0, 12.0),
    ParameterSpec("sky.epoch_jyear", 0.0, "catalog epoch; 0 = the clock's date", "Julian year", 0.0, 2200.0),
    _sensor("sky.photon_flux_hp0"),
    _sensor("sky.color_coefficient"),
    _sensor("sky.background_e_per_px_s"),
    _sensor("sky.stray_light_gradient_e_per_px2_s"),
    ParameterSpec("sky.observer_velocity_m_s", (0.0, 0.0, 0.0), "spacecraft velocity in ICRS, for stellar "
                  "aberration (Earth orbit ~ 30 km/s)", "m/s"),
]
PROFILES = ("fixed", "constant_rate", "slew", "tumble", "jitter", "external", *ORBIT_PROFILES)
ATTITUDE_PARAMETERS = [
    ParameterSpec("attitude.ra_deg", 80.0, "initial boresight right ascension", "deg", -360.0, 360.0),
    ParameterSpec("attitude.dec_deg", 20.0, "initial boresight declination", "deg", -90.0, 90.0),
    ParameterSpec("attitude.roll_deg", 0.0, "initial roll about the boresight", "deg", -360.0, 360.0),
    ParameterSpec("attitude.quaternion", (0.0, 0.0, 0.0, 0.0), "initial sensor->ICRS quaternion x, y, z, w; all "
                  "zero = use ra_deg, dec_deg, roll_deg"),
    ParameterSpec("attitude.profile", "constant_rate", "motion of the body (the camera, with the default "
                  "head.mounting_quaternion); external: follow truth_in/attitude + truth_in/angular_velocity, same "
                  "stamps, this clock; nadir, sun_pointing: with an orbit (orbit.model)", choices=PROFILES),
    ParameterSpec("attitude.body_rate_deg_s", (0.0, 0.0, 0.0), "constant body rate in the sensor frame x, y, z "
                  "(constant_rate, and the jitter base)", "deg/s"),
    ParameterSpec("attitude.slew.axis", (1.0, 0.0, 0.0), "slew axis in the sensor frame"),
    ParameterSpec("attitude.slew.angle_deg", 10.0, "slew angle", "deg", -3600.0, 3600.0),
    ParameterSpec("attitude.slew.max_rate_deg_s", 2.0, "coast rate", "deg/s", 1e-6, 90.0),
    ParameterSpec("attitude.slew.accel_deg_s2", 0.5, "acceleration", "deg/s^2", 1e-6, 1000.0),
    ParameterSpec("attitude.slew.start_s", 2.0, "slew start after the first exposure", "s", 0.0, 1e6),
    ParameterSpec("attitude.tumble.initial_rate_deg_s", (0.5, 0.2, 1.0), "initial body rate", "deg/s"),
    ParameterSpec("attitude.tumble.inertia_kg_m2", (10.0, 12.0, 8.0), "principal moments about the sensor x, y, z "
                  "axes", "kg m^2"),
    ParameterSpec("attitude.jitter.amplitudes_rad", (2e-5, 2e-5, 1e-5), "sinusoid amplitudes x, y, z per term, "
                  "flat (3N values)", "rad"),
    ParameterSpec("attitude.jitter.frequencies_hz", (7.0,), "sinusoid frequencies (N values)", "Hz"),
    ParameterSpec("attitude.jitter.phases_rad", (0.0,), "phases: 1, N or 3N values", "rad"),
]
FAULT_PARAMETERS = [
    ParameterSpec("faults.blank_frames", (-1,), "frame indices rendered with the field occulted (no stars, e.g. "
                  "Earth or a baffle): to exercise loss and re-acquisition; -1 = none"),
]
_PLACED = {spec.name for spec in CAMERA_PARAMETERS + SKY_PARAMETERS}
CAMERA_SIMULATOR_PARAMETERS = [
    *OUTPUT_PARAMETERS, *CAMERA_PARAMETERS,
    *(spec for spec in SENSOR_PARAMETERS if spec.name not in _PLACED), READOUT_PARAMETER,
    *SKY_PARAMETERS, *FALSE_OBJECT_PARAMETERS, *ATTITUDE_PARAMETERS, *ORBIT_PARAMETERS, *FAULT_PARAMETERS, AUTOSTART,
]


def read(p: Declare, specs) -> dict[str, Any]:
    """Read name -> value of `specs` from a parameter source p(name, default, description, low, high)."""
    return {spec.name: p(spec.name, list(spec.default) if isinstance(spec.default, tuple) else spec.default,
                         spec.full_description(), spec.low, spec.high) for spec in specs}


def camera_from(values: dict) -> tuple[CameraModel, float]:
    """Return the image size and optics: (the camera model, the horizontal field of view [deg])."""
    fov_x_deg = values["optics.fov_x_deg"]
    # A distortion of other than 5 values is refused here, by the camera model.
    camera = CameraModel.from_fov(values["image.width"], values["image.height"], np.radians(fov_x_deg),
                                  tuple(values["optics.distortion"]))
    return camera, fov_x_deg


def sensor_from(values: dict) -> SensorModel:
    """Radiometry, detector and shutter parameters (SIMULATED_SENSOR for those not given)."""
    return SensorModel(**{**SIMULATED_SENSOR.__dict__, **field_values(SENSOR_PARAMETERS, values)})


def false_objects_from(values: dict) -> FalseObjectModel:
    """Non-catalog objects in view: planets (points) and debris (streaks)."""
    return FalseObjectModel(**field_values(FALSE_OBJECT_PARAMETERS, values))


def declare_camera(p: Declare) -> tuple[CameraModel, float]:
    """camera_from the parameter source p (see read)."""
    return camera_from(read(p, [s for s in CAMERA_PARAMETERS if s.field is None]))


def declare_sensor(p: Declare) -> SensorModel:
    """sensor_from the parameter source p (see read)."""
    return sensor_from(read(p, SENSOR_PARAMETERS))


@dataclass(frozen=True)
class SkySetup:
    """What the sky holds and how it looks from the spacecraft."""

    magnitude_limit: float  # faintest star rendered [Hp mag]
    epoch_jyear: float  # catalog epoch [Julian year]; 0 = the clock's date
    observer_velocity_m_s: list  # spacecraft velocity in ICRS, for aberration [m/s]
    fixed_pattern_seed: int  # seed of PRNU, DSNU and hot pixels


def sky_from(values: dict) -> SkySetup:
    return SkySetup(magnitude_limit=values["sky.magnitude_limit"], epoch_jyear=values["sky.epoch_jyear"],
                    observer_velocity_m_s=values["sky.observer_velocity_m_s"],
                    fixed_pattern_seed=values["fixed_pattern_seed"])


@dataclass(frozen=True)
class AttitudeSetup:
    """The motion the simulated camera follows."""

    profile: str  # fixed, constant_rate, slew, tumble, jitter or external
    initial_rotation: np.ndarray  # sensor -> ICRS rotation matrix at the first exposure
    motion_kwargs: dict  # profile -> keyword arguments of motion_from_parameters (SI units, radians)


def motion_kwargs_from(values: dict) -> dict:
    """Every profile's motion parameters (all declared, whichever profile runs), in radians."""
    deg, v = np.radians, values
    body_rate = deg(v["attitude.body_rate_deg_s"])
    return {
        "fixed": {},
        "constant_rate": {"body_rate_rad_s": body_rate},
        "slew": {"axis": v["attitude.slew.axis"], "angle_rad": deg(v["attitude.slew.angle_deg"]),
                 "max_rate_rad_s": deg(v["attitude.slew.max_rate_deg_s"]),
                 "accel_rad_s2": deg(v["attitude.slew.accel_deg_s2"]), "t_start": v["attitude.slew.start_s"]},
        "tumble": {"initial_rate_rad_s": deg(v["attitude.tumble.initial_rate_deg_s"]),
                   "inertia_kg_m2": v["attitude.tumble.inertia_kg_m2"]},
        "jitter": {"body_rate_rad_s": body_rate, "amplitudes_rad": v["attitude.jitter.amplitudes_rad"],
                   "frequencies_hz": v["attitude.jitter.frequencies_hz"],
                   "phases_rad": v["attitude.jitter.phases_rad"]},
    }


def attitude_from(values: dict) -> AttitudeSetup:
    """
    Return the initial attitude (a quaternion, else RA/Dec/roll) and the motion profile, checked.

    A bad profile fails at startup, not at the first frame.
    """
    quaternion = values["attitude.quaternion"]
    ra, dec, roll = (np.radians(values[f"attitude.{k}"]) for k in ("ra_deg", "dec_deg", "roll_deg"))
    profile = values["attitude.profile"]
    motion_kwargs = motion_kwargs_from(values)
    if profile not in (*motion_kwargs, "external", *ORBIT_PROFILES):
        raise ValueError(f"attitude.profile={profile!r}: expected one of {sorted(PROFILES)}")
    if len(quaternion) != 4:  # (the camera model has refused a distortion of other than 5 values)
        raise ValueError("optics.distortion needs 5 values, attitude.quaternion 4")
    if not np.all(np.isfinite(quaternion)):  # NaN would fall through to RA/Dec/roll unnoticed
        raise ValueError(f"attitude.quaternion={list(quaternion)} must be finite")
    if np.linalg.norm(quaternion) > 0:
        initial = quaternion_to_matrix(np.asarray(quaternion, dtype=float))
    else:
        initial = radec_roll_to_matrix(ra, dec, roll)
    if profile not in ("external", *ORBIT_PROFILES):  # (the orbit profiles are checked with the orbit)
        motion_from_parameters(profile, initial, **motion_kwargs[profile])
    return AttitudeSetup(profile, initial, motion_kwargs)
