# SPDX-License-Identifier: Apache-2.0
"""`star-tracker render`: one simulated frame to a 16-bit PNG/TIFF or FITS, with its truth as JSON."""
from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .camera_files import CameraFile, camera_summary, default_camera_file, load_camera_file
from .common import CommandError, add_parser, finite_float, guarded, positive_float

NAME = "render"


def register(subparsers) -> None:
    parser = add_parser(
        subparsers, NAME, "render one simulated star-field frame to PNG/FITS with a truth JSON",
        "Render one frame of the Hipparcos sky with the camera simulator's model (radiometry, "
        "pixel-integrated PSF, motion smear over the exposure, detector noise and defects) and write "
        "it losslessly as a 16-bit PNG or TIFF, or as FITS (by the output's suffix). Beside it goes "
        "the truth as JSON: the attitude at mid-exposure (quaternion x, y, z, w sensor->ICRS, and "
        "RA/Dec/roll), the body rate, the stamp, the camera, and every rendered star's HIP id, Hp "
        "magnitude and pixel position. Conventions: docs/USER_GUIDE.md and msg_docs/.",
        "star-tracker render --ra 83.8 --dec -5.4 --roll 30 --rate 0.1 0 0 --output orion.png\n"
        "star-tracker solve orion.png --fov 15    # should give back RA 83.8, Dec -5.4, roll 30")
    parser.add_argument("--ra", type=finite_float, default=80.0, metavar="DEG",
                        help="boresight right ascension, ICRS [deg] (default 80)")
    parser.add_argument("--dec", type=finite_float, default=20.0, metavar="DEG",
                        help="boresight declination, ICRS [deg], -90..90 (default 20)")
    parser.add_argument("--roll", type=finite_float, default=0.0, metavar="DEG",
                        help="roll about the boresight [deg]; 0 = image up (-y) toward celestial north (default 0)")
    parser.add_argument("--rate", type=finite_float, nargs=3, default=[0.0, 0.0, 0.0], metavar=("WX", "WY", "WZ"),
                        help="body rate in the sensor frame (+x image right, +y image down, +z boresight) "
                             "[deg/s] (default 0 0 0: no smear)")
    parser.add_argument("--exposure", type=positive_float, default=None, metavar="S",
                        help="exposure time [s] (default: sensor.exposure_s of --camera, else 0.1)")
    parser.add_argument("--seed", type=int, default=0,
                        help="noise seed: the frame is reproducible from it (default 0)")
    parser.add_argument("--stamp", type=finite_float, default=0.0, metavar="S",
                        help="mid-exposure time written to the truth [s] (default 0)")
    parser.add_argument("--camera", metavar="YAML",
                        help="camera file: camera_simulator parameters as in config/star_tracker.yaml "
                             "(image.width, optics.fov_x_deg, sensor.*, sky.*; unset keys keep the node's "
                             "defaults). Default: the node's default camera, 1024x1024 px, 15 deg")
    parser.add_argument("--magnitude-limit", type=finite_float, default=None, metavar="HP",
                        help="faintest star rendered [Hp mag] (default: sky.magnitude_limit of --camera, else 7.5)")
    parser.add_argument("--epoch", type=finite_float, default=None, metavar="YEAR",
                        help="catalog epoch for proper motion [Julian year] (default: sky.epoch_jyear of --camera "
                             "if set, else 2026.0)")
    parser.add_argument("--no-noise", action="store_true",
                        help="render expected values: no shot/read noise, no cosmic rays (default: noise on)")
    parser.add_argument("-o", "--output", required=True, metavar="FILE",
                        help="image to write: .png or .tif/.tiff (16-bit grey) or .fits/.fit")
    parser.add_argument("--truth", metavar="JSON",
                        help="truth file to write (default: the output's name with .json)")
    parser.set_defaults(func=run)


def truth_path_for(output: Path) -> Path:
    name = output.name
    for suffix in (".fits.gz", ".fit.gz"):
        if name.lower().endswith(suffix):
            return output.with_name(name[: -len(suffix)] + ".json")
    return output.with_suffix(".json")


@dataclass(frozen=True)
class RenderSetup:
    """
    What a render draws with.

    `spec` (camera, false objects, render keys and source of the camera file or the default
    camera), `sensor` with --exposure and --no-noise applied, magnitude_limit [Hp mag] and
    the catalog epoch [Julian year].
    """

    spec: CameraFile
    sensor: object  # sim.sensor.SensorModel
    magnitude_limit: float
    epoch: float


@guarded(NAME)
def run(args: argparse.Namespace) -> int:
    from .images import write_image

    if not -90.0 <= args.dec <= 90.0:
        raise CommandError(f"--dec {args.dec} must be in [-90, 90]")
    output = Path(args.output)
    truth_path = Path(args.truth) if args.truth else truth_path_for(output)
    if output.resolve() == truth_path.resolve():
        raise CommandError("--truth must differ from --output")
    setup = render_setup(args)
    renderer, frame = render_frame(args, setup)
    document = truth_document(args, setup, renderer.catalog, frame.truth, output)
    write_image(output, frame.image, fits_header(document))
    truth_path.write_text(json.dumps(document, indent=1) + "\n")
    cam = setup.spec.camera
    in_view = sum(1 for s in document["stars"] if s["in_image"])
    print(f"wrote {output} ({cam.width}x{cam.height} uint16, {camera_summary(cam)}; exposure "
          f"{setup.sensor.exposure_s:g} s, {in_view} stars to Hp {setup.magnitude_limit:g} in the image)")
    print(f"wrote {truth_path} (RA {document['ra_deg']:.4f} deg, Dec {document['dec_deg']:.4f} deg, "
          f"roll {document['roll_deg']:.4f} deg, rate {' '.join(f'{w:g}' for w in args.rate)} deg/s)")
    return 0


def render_setup(args: argparse.Namespace) -> RenderSetup:
    """
    Return the camera file (or the default camera, node detector defaults) with the command line's exposure.

    Noise, magnitude limit and epoch applied; CommandError for a calibration-only file or an
    epoch outside [1900, 2200].
    """
    from dataclasses import replace

    if args.camera:
        spec = load_camera_file(args.camera)
        if spec.sensor is None:
            raise CommandError(f"{args.camera}: a calibration file has no sensor model; render needs "
                               "camera_simulator parameters")
    else:
        spec = default_camera_file()
    sensor = spec.sensor
    if args.exposure is not None:
        sensor = replace(sensor, exposure_s=args.exposure)
    if args.no_noise:
        sensor = replace(sensor, noise=False, cosmic_ray_rate_per_cm2_s=0.0)
    magnitude_limit = args.magnitude_limit if args.magnitude_limit is not None else float(
        spec.render.get("magnitude_limit", 7.5))
    epoch = args.epoch if args.epoch is not None else float(spec.render.get("epoch_jyear") or 2026.0)
    if not 1900.0 <= epoch <= 2200.0:
        raise CommandError(f"epoch {epoch} must be in [1900, 2200]")
    return RenderSetup(spec, sensor, magnitude_limit, epoch)


def render_frame(args: argparse.Namespace, setup: RenderSetup):
    """
    Return the renderer and its frame at --stamp.

    For the pointing (--ra, --dec, --roll [deg]) and the constant body rate --rate [deg/s].
    """
    from ..models.attitude import radec_roll_to_matrix
    from ..models.catalog import load_hipparcos
    from ..sim.motion import ConstantRateMotion
    from ..sim.render import StarFieldRenderer, frame_seed

    spec = setup.spec
    catalog = load_hipparcos().at_epoch(setup.epoch)
    renderer = StarFieldRenderer(spec.camera, setup.sensor, catalog, setup.magnitude_limit, spec.false_objects,
                                 int(spec.render.get("fixed_pattern_seed", 0)),
                                 spec.render.get("observer_velocity_m_s", (0.0, 0.0, 0.0)))
    rotation = radec_roll_to_matrix(math.radians(args.ra), math.radians(args.dec), math.radians(args.roll))
    rate = np.radians(np.asarray(args.rate, dtype=float))
    motion = ConstantRateMotion(rotation, rate, t0=args.stamp)
    return renderer, renderer.render(motion, args.stamp, frame_seed(args.seed, 0))


def truth_document(args: argparse.Namespace, setup: RenderSetup, catalog, truth, output: Path) -> dict:
    """
    Return the truth JSON: attitude at mid-exposure (quaternion, RA/Dec/roll [deg], matrix), body rate [deg/s], stamp.

    Exposure, seed, epoch, magnitude limit, camera, and every rendered star (HIP, Hp, pixel
    position, electrons) and other object. catalog: the renderer's.
    """
    from ..models.attitude import matrix_to_quaternion, matrix_to_radec_roll

    ra, dec, roll = (math.degrees(a) for a in matrix_to_radec_roll(truth.rotation))
    quaternion = matrix_to_quaternion(truth.rotation)
    cam = setup.spec.camera
    return {
        "image": str(output.name),
        "stamp_s": truth.stamp_s,
        "quaternion_xyzw": [float(q) for q in quaternion],
        "ra_deg": ra, "dec_deg": dec, "roll_deg": roll,
        "rotation_sensor_to_icrs": truth.rotation.tolist(),
        "body_rate_deg_s": [float(w) for w in np.degrees(truth.body_rate)],
        "exposure_s": setup.sensor.exposure_s,
        "seed": int(args.seed),
        "epoch_jyear": setup.epoch,
        "magnitude_limit": setup.magnitude_limit,
        "camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy,
                   "distortion": list(cam.distortion),
                   "fov_x_deg": math.degrees(2 * math.atan(0.5 * cam.width / cam.fx)), "source": setup.spec.source},
        "stars": star_rows(catalog, truth, cam),
        "other_objects": other_object_rows(truth),
        "conventions": "quaternion (x, y, z, w) rotates sensor-frame vectors into ICRS; sensor frame +x image right, "
                       "+y image down, +z boresight; pixel (0, 0) is the centre of the top-left pixel; positions "
                       "at mid-exposure; magnitudes Hipparcos Hp",
    }


def star_rows(catalog, truth, camera) -> list[dict]:
    """Per rendered star: HIP, Hp magnitude, pixel position [px], electrons [e-], in the image."""
    from ..sim.render import KIND_STAR

    stars = truth.kind == KIND_STAR
    by_hip = np.argsort(catalog.hip)
    index = by_hip[np.searchsorted(catalog.hip, truth.hip[stars], sorter=by_hip)]
    magnitude = catalog.hp[index]
    inside = camera.in_image(truth.x, truth.y)
    return [{"hip": int(h), "magnitude": round(float(m), 3), "x": round(float(x), 4), "y": round(float(y), 4),
             "electrons": round(float(e), 1), "in_image": bool(i)}
            for h, m, x, y, e, i in zip(truth.hip[stars], magnitude, truth.x[stars], truth.y[stars],
                                        truth.electrons[stars], inside[stars])]


def other_object_rows(truth) -> list[dict]:
    """Per non-star object (planet, debris, cosmic ray, hot pixel): kind, position [px], electrons."""
    from ..sim.render import KIND_STAR

    others = truth.kind != KIND_STAR
    return [{"kind": int(k), "x": round(float(x), 4), "y": round(float(y), 4), "electrons": round(float(e), 1)}
            for k, x, y, e in zip(truth.kind[others], truth.x[others], truth.y[others], truth.electrons[others])]


def fits_header(document: dict) -> dict:
    """FITS header cards (value, comment) of a render, from its truth document."""
    return {"EXPTIME": (document["exposure_s"], "[s] exposure"), "RA": (document["ra_deg"], "[deg] boresight RA, ICRS"),
            "DEC": (document["dec_deg"], "[deg] boresight Dec, ICRS"),
            "ROLL": (document["roll_deg"], "[deg] roll about the boresight"),
            "FOVX": (document["camera"]["fov_x_deg"], "[deg] horizontal FOV"),
            "SEED": (document["seed"], "noise seed"), "CREATOR": ("star-tracker render", "")}
