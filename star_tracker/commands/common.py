"""What the `star-tracker` subcommands share: one-line errors, argument types, progress lines,
camera files and the pattern-database configuration for a field of view."""
from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

# The identifier's default database (config/star_tracker.yaml): 15 deg cameras use exactly it.
DEFAULT_DB_MAGNITUDE = 6.5
DEFAULT_EPOCH_JYEAR = 2026.0
# Guide stars wanted in a field of view when the magnitude limit is chosen automatically.
STARS_WANTED_IN_VIEW = 10.0
MAX_AUTO_MAGNITUDE = 8.0


class CommandError(ValueError):
    """A problem with the user's input: printed as one line, exit code 2."""


def guarded(command: str, errors: tuple[type[Exception], ...] = ()) -> Callable:
    """Decorator for a subcommand's run(args): bad input (ValueError, FileNotFoundError, other
    OSError, and the command's own `errors`, e.g. bags.BagError) becomes
    `star-tracker <command>: error: ...` on stderr and exit code 2; Ctrl-C exit code 130.
    Anything else is a bug and keeps its traceback."""

    def wrap(run: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
        @functools.wraps(run)
        def guarded_run(args: argparse.Namespace) -> int:
            try:
                return run(args)
            except BrokenPipeError:  # output piped into `head` & co.: not an error of ours
                sys.stderr.close()
                return 141
            except FileNotFoundError as exc:
                name = exc.filename if exc.filename is not None else str(exc)
                error(command, f"no such file: {name}" if exc.filename is not None else str(exc))
                return 2
            except (ValueError, OSError, *errors) as exc:
                error(command, str(exc) or type(exc).__name__)
                return 2
            except KeyboardInterrupt:
                print(file=sys.stderr)
                return 130

        return guarded_run

    return wrap


def error(command: str, message: str) -> None:
    print(f"star-tracker {command}: error: {message}", file=sys.stderr, flush=True)


def _float_argument(accept, requirement: str):
    """An argparse type: a finite float for which accept(value) holds, else '<text> must be <requirement>'."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (math.isfinite(value) and accept(value)):
            raise argparse.ArgumentTypeError(f"{text} must be {requirement}")
        return value
    return parse


positive_float = _float_argument(lambda v: v > 0, "> 0")
non_negative_float = _float_argument(lambda v: v >= 0, ">= 0")
finite_float = _float_argument(lambda v: True, "finite")


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text} must be >= 1")
    return value


class HelpFormatter(argparse.HelpFormatter):
    """Wraps the description like argparse does, but keeps the epilog's example lines as written."""

    def _fill_text(self, text, width, indent):
        if text.startswith("example"):
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def add_parser(subparsers, name: str, summary: str, description: str, example: str) -> argparse.ArgumentParser:
    """A subcommand parser with the summary in `star-tracker --help`, a description and an
    example epilog in `star-tracker NAME --help`."""
    return subparsers.add_parser(name, help=summary, description=description,
                                 epilog="example:\n" + "\n".join("  " + line for line in example.strip().splitlines()),
                                 formatter_class=HelpFormatter)


# ---------------------------------------------------------------- progress

def progress_bar(fraction: float, width: int = 28) -> str:
    """`[#####.......]` for a fraction in [0, 1]."""
    filled = int(round(min(max(fraction, 0.0), 1.0) * width))
    return f"[{'#' * filled}{'.' * (width - filled)}]"


class StatusLine:
    """One status line on a stream (stderr by default): redrawn in place on a terminal; on
    anything else (logs, pipes) appended as a new line at most every `min_interval_s`, and
    always when `final`."""

    def __init__(self, stream=None, min_interval_s: float = 2.0):
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.min_interval_s = min_interval_s
        self._last_line = -math.inf
        self._shown = False

    def show(self, line: str, final: bool = False) -> None:
        if self.tty:
            self.stream.write("\r\x1b[K" + line + ("\n" if final else ""))
            self._shown = not final
        elif final or time.perf_counter() - self._last_line >= self.min_interval_s:
            self.stream.write(line + "\n")
            self._last_line = time.perf_counter()
        else:
            return
        self.stream.flush()

    def clear(self) -> None:
        """Erase a line being redrawn (terminal only), before other output is printed."""
        if self.tty and self._shown:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self._shown = False


class Progress:
    """A one-line progress bar on stderr (StatusLine): label, bar, done/total, elapsed time
    and a note."""

    def __init__(self, total: int, label: str, width: int = 28, stream=None, min_interval_s: float = 2.0):
        self.total, self.label, self.width = max(int(total), 1), label, width
        self.line = StatusLine(stream, min_interval_s)
        self.started = time.perf_counter()
        self.done = 0

    def update(self, done: int | None = None, note: str = "") -> None:
        self.done = self.done + 1 if done is None else int(done)
        self._draw(note, final=self.done >= self.total)

    def _draw(self, note: str, final: bool = False) -> None:
        elapsed = time.perf_counter() - self.started
        self.line.show(f"{self.label} {progress_bar(self.done / self.total, self.width)} {self.done}/{self.total} "
                       f"{elapsed:6.1f} s{'  ' + note if note else ''}", final)


# ---------------------------------------------------------------- databases

def field_diagonal_rad(fov_x_rad: float, width: int, height: int) -> float:
    """Full diagonal field of a pinhole camera of horizontal FOV fov_x_rad [rad]."""
    f = 0.5 * width / math.tan(0.5 * fov_x_rad)
    return 2.0 * math.atan(0.5 * math.hypot(width, height) / f)


def auto_magnitude_limit(fov_x_rad: float, width: int, height: int) -> float:
    """Faintest guide star for a field: the default 6.5 for fields of ~7 deg and wider, fainter
    for narrower fields so that ~STARS_WANTED_IN_VIEW guide stars are in view on average
    (star counts grow ~x2.5 per magnitude near Hp 7), at most MAX_AUTO_MAGNITUDE."""
    f = 0.5 * width / math.tan(0.5 * fov_x_rad)
    solid_angle_deg2 = (width / f) * (height / f) * (180.0 / math.pi) ** 2
    density_at_default = 8000.0 / 41253.0  # Hipparcos stars to Hp 6.5 per square degree
    expected = density_at_default * solid_angle_deg2
    if expected >= STARS_WANTED_IN_VIEW:
        return DEFAULT_DB_MAGNITUDE
    extra = math.log(STARS_WANTED_IN_VIEW / expected) / math.log(2.5)
    return round(min(DEFAULT_DB_MAGNITUDE + extra, MAX_AUTO_MAGNITUDE), 1)


def database_config_for(fov_x_rad: float, width: int, height: int, magnitude_limit: float | None = None,
                        epoch_jyear: float = DEFAULT_EPOCH_JYEAR):
    """The pattern-database configuration for a pinhole camera of horizontal FOV fov_x_rad
    [rad] on width x height px: pairs as DatabaseConfig.for_camera derives them; guide stars
    to `magnitude_limit` (None: auto_magnitude_limit)."""
    from ..identify import DatabaseConfig
    from ..models.camera import CameraModel

    limit = auto_magnitude_limit(fov_x_rad, width, height) if magnitude_limit is None else float(magnitude_limit)
    return DatabaseConfig.for_camera(CameraModel.from_fov(width, height, fov_x_rad), limit, epoch_jyear)


# ---------------------------------------------------------------- camera files

# camera_simulator parameter -> SensorModel field (config/star_tracker.yaml names).
SENSOR_PARAMETERS = {
    "optics.aperture_diameter_m": "aperture_diameter_m",
    "optics.transmission": "optical_transmission",
    "optics.psf_sigma_px": "psf_sigma_px",
    "optics.vignetting_at_corner": "vignetting_at_corner",
    "sky.photon_flux_hp0": "photon_flux_hp0",
    "sky.color_coefficient": "color_coefficient",
    "sky.background_e_per_px_s": "background_e_per_px_s",
    "sky.stray_light_gradient_e_per_px2_s": "stray_light_gradient_e_per_px2_s",
    "sensor.exposure_s": "exposure_s",
    "sensor.pixel_pitch_m": "pixel_pitch_m",
    "sensor.quantum_efficiency": "quantum_efficiency",
    "sensor.dark_e_per_px_s": "dark_e_per_px_s",
    "sensor.dark_reference_k": "dark_reference_k",
    "sensor.dark_doubling_k": "dark_doubling_k",
    "sensor.temperature_k": "temperature_k",
    "sensor.dsnu_fraction": "dsnu_fraction",
    "sensor.prnu_fraction": "prnu_fraction",
    "sensor.hot_pixel_fraction": "hot_pixel_fraction",
    "sensor.hot_pixel_dark_factor": "hot_pixel_dark_factor",
    "sensor.cosmic_ray_rate_per_cm2_s": "cosmic_ray_rate_per_cm2_s",
    "sensor.cosmic_ray_electrons": "cosmic_ray_electrons",
    "sensor.read_noise_e": "read_noise_e",
    "sensor.gain_e_per_adu": "gain_e_per_adu",
    "sensor.bias_adu": "bias_adu",
    "sensor.full_well_e": "full_well_e",
    "sensor.adc_bits": "adc_bits",
    "sensor.rolling_shutter_row_time_s": "rolling_shutter_row_time_s",
    "sensor.frame_transfer_time_s": "frame_transfer_time_s",
    "sensor.noise": "noise",
}
FALSE_OBJECT_PARAMETERS = {
    "false_objects.planets_per_frame": "planets_per_frame",
    "false_objects.planet_magnitude_range": "planet_magnitude_range",
    "false_objects.debris_per_frame": "debris_per_frame",
    "false_objects.debris_magnitude_range": "debris_magnitude_range",
    "false_objects.debris_speed_px_s": "debris_speed_px_s",
}
GEOMETRY_PARAMETERS = ("image.width", "image.height", "optics.fov_x_deg", "optics.distortion")
RENDER_PARAMETERS = ("sky.magnitude_limit", "sky.epoch_jyear", "sky.observer_velocity_m_s", "fixed_pattern_seed", "seed")
# camera_simulator parameters that describe the run, not the camera: accepted and ignored.
IGNORED_PREFIXES = ("rate_hz", "max_frames", "start_delay_s", "wait_for_subscribers", "max_backlog_frames",
                    "frame_id", "attitude.", "faults.", "sensor.readout_s")  # readout: when a frame is published


class CameraFile:
    """A camera read from YAML: `camera` (CameraModel), and for rendering `sensor`
    (SensorModel), `false_objects` (FalseObjectModel) and `render` (magnitude_limit,
    epoch_jyear, observer_velocity_m_s, fixed_pattern_seed, seed: those given)."""

    def __init__(self, camera, sensor, false_objects, render: dict, source: str):
        self.camera, self.sensor, self.false_objects, self.render, self.source = camera, sensor, false_objects, render, source


def _flatten(mapping: dict, prefix: str = "") -> dict:
    flat = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, name + "."))
        else:
            flat[name] = value
    return flat


def load_camera_file(path: str | Path):
    """Read a camera YAML: either camera_simulator parameters (a ros2 param file like
    config/star_tracker.yaml, its `/**/camera_simulator: ros__parameters:` block, or the same
    keys as a plain mapping, nested or dotted: image.width, optics.fov_x_deg, sensor.*, ...;
    unset keys keep the node's defaults), or a ROS camera calibration file (image_width,
    image_height, camera_matrix.data, distortion_coefficients.data, as written by
    camera_calibration) for `solve` with a calibrated camera. Unknown keys are an error."""
    import yaml

    from ..models.camera import CameraModel
    from ..sim.render import FalseObjectModel, SensorModel

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
    flat = _flatten(data)
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
        # The node's defaults where they differ from SensorModel's (config/star_tracker.yaml).
        sensor_values = {"vignetting_at_corner": 0.1, "dsnu_fraction": 0.1, "prnu_fraction": 0.01,
                         "hot_pixel_fraction": 2e-5, "cosmic_ray_rate_per_cm2_s": 5.0}
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
    return (f"{camera.width}x{camera.height} px, FOV {math.degrees(2 * math.atan(0.5 * camera.width / camera.fx)):.3f} deg "
            f"(fx {camera.fx:.2f} px, {math.degrees(camera.pixel_scale_rad) * 3600:.2f}\"/px)")
