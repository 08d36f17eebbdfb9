# SPDX-License-Identifier: Apache-2.0
"""
Camera files of the `star-tracker` subcommands.

camera_simulator parameters (a ros2 param file like config/star_tracker.yaml, or the same
keys as a mapping) read into a CameraModel, SensorModel and FalseObjectModel for `render`,
or a ROS camera calibration file for `solve`; and the one-line camera summary the commands
print.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..parameter_spec import dotted_names
from ..ros import camera_simulator_parameters as _node  # ROS-free: the parameter specs
from .common import CommandError

# camera_simulator parameter -> SensorModel / FalseObjectModel field: from the node's parameter specs.
SENSOR_PARAMETERS = {spec.name: spec.field for spec in _node.SENSOR_PARAMETERS}
FALSE_OBJECT_PARAMETERS = {spec.name: spec.field for spec in _node.FALSE_OBJECT_PARAMETERS}
GEOMETRY_PARAMETERS = ("image.width", "image.height", "optics.fov_x_deg", "optics.distortion")
RENDER_PARAMETERS = ("sky.magnitude_limit", "sky.epoch_jyear", "sky.observer_velocity_m_s", "fixed_pattern_seed",
                     "seed")
# camera_simulator parameters that describe the run, not the camera: accepted and ignored.
IGNORED_PREFIXES = ("rate_hz", "max_frames", "start_delay_s", "wait_for_subscribers", "max_backlog_frames",
                    "frame_id", "attitude.", "faults.", "sensor.readout_s")  # readout: when a frame is published
# The camera_simulator node's defaults where they differ from SensorModel's (config/star_tracker.yaml).
NODE_SENSOR_DEFAULTS = {name: value for name, value in vars(_node.SIMULATED_SENSOR).items()
                        if value != getattr(_node.SensorModel(), name)}


class CameraFile:
    """
    A camera read from YAML.

    `camera` (CameraModel), and for rendering `sensor` (SensorModel), `false_objects`
    (FalseObjectModel) and `render` (magnitude_limit, epoch_jyear, observer_velocity_m_s,
    fixed_pattern_seed, seed: those given).
    """

    def __init__(self, camera, sensor, false_objects, render: dict, source: str):
        self.camera, self.sensor, self.false_objects = camera, sensor, false_objects
        self.render, self.source = render, source


def default_camera_file() -> CameraFile:
    """
    Return the camera_simulator node's default camera.

    1024 x 1024 px, 15 deg, the node's sensor defaults (NODE_SENSOR_DEFAULTS), no false
    objects.
    """
    from ..models.camera import CameraModel
    from ..sim.render import FalseObjectModel
    from ..sim.sensor import SensorModel

    return CameraFile(CameraModel.from_fov(1024, 1024, np.radians(15.0)), SensorModel(**NODE_SENSOR_DEFAULTS),
                      FalseObjectModel(), {}, "default camera")


def load_camera_file(path: str | Path):
    """
    Read a camera YAML.

    Either camera_simulator parameters (a ros2 param file like config/star_tracker.yaml, its
    `/**/camera_simulator: ros__parameters:` block, or the same keys as a plain mapping,
    nested or dotted: image.width, optics.fov_x_deg, sensor.*, ...; unset keys keep the
    node's defaults), or a ROS camera calibration file (image_width, image_height,
    camera_matrix.data, distortion_coefficients.data, as written by camera_calibration) for
    `solve` with a calibrated camera. Unknown keys are an error.
    """
    import yaml

    from ..models.camera import CameraModel
    from ..sim.render import FalseObjectModel
    from ..sim.sensor import SensorModel

    path = Path(path)
    with open(path) as handle:  # FileNotFoundError names the file
        try:
            data = yaml.safe_load(handle)
        except yaml.YAMLError as exc:
            raise CommandError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise CommandError(f"{path}: expected a mapping of camera parameters")
    if "camera_matrix" in data:
        return _calibration_file(data, path)
    for key in ("/**/camera_simulator", "camera_simulator", "/camera_simulator"):
        if key in data:
            data = data[key]
            break
    if isinstance(data, dict) and "ros__parameters" in data:
        data = data["ros__parameters"]
    if not isinstance(data, dict):
        raise CommandError(f"{path}: expected camera_simulator parameters")
    flat = dotted_names(data)
    known = set(SENSOR_PARAMETERS) | set(FALSE_OBJECT_PARAMETERS) | set(GEOMETRY_PARAMETERS) | set(RENDER_PARAMETERS)
    unknown = sorted(k for k in flat if k not in known and not k.startswith(IGNORED_PREFIXES))
    if unknown:
        raise CommandError(f"{path}: unknown camera parameter(s) {', '.join(unknown)} (expected the "
                           "camera_simulator's parameter names, e.g. image.width, optics.fov_x_deg, sensor.exposure_s)")
    try:
        width, height = int(flat.get("image.width", 1024)), int(flat.get("image.height", 1024))
        fov = float(flat.get("optics.fov_x_deg", 15.0))
        distortion = tuple(float(d) for d in flat.get("optics.distortion", [0.0] * 5))
        if not 0.5 <= fov <= 120.0:
            raise CommandError(f"{path}: optics.fov_x_deg={fov} must be in [0.5, 120]")
        camera = CameraModel.from_fov(width, height, np.radians(fov), distortion)
        sensor_values = dict(NODE_SENSOR_DEFAULTS)
        for name, field in SENSOR_PARAMETERS.items():
            if name in flat:
                value = flat[name]
                sensor_values[field] = tuple(value) if isinstance(value, list) else value
        sensor = SensorModel(**sensor_values)
        false_objects = FalseObjectModel(**{field: tuple(flat[name]) if isinstance(flat[name], list) else flat[name]
                                            for name, field in FALSE_OBJECT_PARAMETERS.items() if name in flat})
    except (TypeError, ValueError) as exc:
        raise CommandError(f"{path}: {exc}") from None
    render = {name.split(".")[-1]: flat[name] for name in RENDER_PARAMETERS if name in flat}
    return CameraFile(camera, sensor, false_objects, render, str(path))


def _calibration_file(data: dict, path: Path):
    from ..models.camera import CameraModel

    try:
        k = np.asarray(data["camera_matrix"]["data"], dtype=float).reshape(3, 3)
        d = list(np.asarray(data.get("distortion_coefficients", {}).get("data", [0.0] * 5), dtype=float))
        d = (d + [0.0] * 5)[:5]
        camera = CameraModel(int(data["image_width"]), int(data["image_height"]), k[0, 0], k[1, 1], k[0, 2], k[1, 2],
                             tuple(d))
    except (KeyError, TypeError, ValueError) as exc:
        raise CommandError(f"{path}: not a usable camera calibration file ({exc})") from None
    return CameraFile(camera, None, None, {}, str(path))


def camera_summary(camera) -> str:
    """One line: size, horizontal FOV [deg], focal length [px] and pixel scale [arcsec/px]."""
    return (f"{camera.width}x{camera.height} px, FOV {math.degrees(2 * math.atan(0.5 * camera.width / camera.fx)):.3f} "
            f"deg (fx {camera.fx:.2f} px, {math.degrees(camera.pixel_scale_rad) * 3600:.2f}\"/px)")
