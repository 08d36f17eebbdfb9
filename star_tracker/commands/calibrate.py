# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker calibrate IMAGE...`.

One camera fitted over several star images, written as a ROS camera calibration file.

Each image is solved as `solve` does (centroid, field search, per-image refinement); the
matched stars of all solved images then fit ONE camera jointly with every image's attitude
(models/camera_calibration.py: focal length, k1, k2 and the principal point where the stars
constrain them); every image is identified once more with that camera and the fit repeated
over the (usually more) stars. The result is a `camera_calibration` YAML file (image_width,
image_height, camera_name, camera_matrix, distortion_model plumb_bob, distortion_coefficients,
rectification_matrix, projection_matrix) that `solve --camera` reads back; the uncertainties
and residuals are in its comments and in a `star_tracker_calibration` key that ROS readers
ignore.
"""
from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np

from ..bags.format import BagError
from .camera_files import load_camera_file
from .common import CommandError, add_parser, guarded, non_negative_float, positive_float, positive_int

NAME = "calibrate"


def register(subparsers) -> None:
    parser = add_parser(
        subparsers, NAME, "fit one camera (focal length, distortion, principal point) over several star images",
        "Solve every image lost-in-space (as `solve`), then fit ONE camera to the matched stars of all solved "
        "images jointly with each image's attitude by weighted least squares: the focal length always, the "
        "radial distortion k1, k2 and the principal point only where the stars constrain them (1-sigma effect "
        "at the image corner <= 2 px; principal point 1-sigma <= 3 px). Each image is identified once more "
        "with the fitted camera and the fit repeated. Writes a ROS camera calibration YAML (plumb_bob) that "
        "`solve --camera` reads, with the 1-sigma uncertainties and residuals as comments and under "
        "star_tracker_calibration; prints a summary (per image: stars, residual RMS; the fit). Images must "
        "share one size. Exit code 0: calibrated; 1: fewer than one image solved; 2: bad input.",
        "star-tracker calibrate night/*.jpg --fov 27 --output camera.yaml\n"
        "star-tracker solve night/frame_0007.jpg --camera camera.yaml")
    parser.add_argument("images", nargs="*", help="image files (PNG/TIFF/JPEG/FITS as `solve` reads), one camera")
    parser.add_argument("--bag", metavar="BAG", help="also take the sensor_msgs/Image messages of a rosbag2 bag "
                                                     "(directory or .db3/.mcap; mono8/mono16)")
    parser.add_argument("--topic", default="/image_raw", help="image topic of --bag (default /image_raw)")
    parser.add_argument("--every", type=positive_int, default=1, metavar="N",
                        help="with --bag: every N-th image (default 1: all)")
    parser.add_argument("--max-images", type=positive_int, default=50, metavar="N",
                        help="with --bag: at most N images from it (default 50)")
    camera = parser.add_mutually_exclusive_group(required=True)
    camera.add_argument("--fov", type=positive_float, metavar="DEG",
                        help="approximate horizontal field of view [deg] (searched within --fov-tolerance)")
    camera.add_argument("--camera", metavar="YAML", help="a first camera (as `solve --camera`) to start from")
    parser.add_argument("--output", "-o", required=True, metavar="YAML", help="camera calibration file to write")
    parser.add_argument("--camera-name", default="star_tracker", help="camera_name in the file (default star_tracker)")
    parser.add_argument("--fov-tolerance", type=non_negative_float, default=5.0, metavar="PCT",
                        help="with --fov: search fields within +-PCT percent (default 5)")
    parser.add_argument("--fov-step", type=positive_float, default=0.5, metavar="PCT",
                        help="step of that search [percent] (default 0.5)")
    parser.add_argument("--detection-sigma", type=positive_float, default=4.5, metavar="K",
                        help="detection threshold [noise sigmas] (default 4.5)")
    parser.add_argument("--psf-sigma", type=non_negative_float, default=None, metavar="PX",
                        help="fix the optics' PSF 1-sigma [px] (default: estimated from each image's stars; "
                             "0 = centre of gravity)")
    parser.add_argument("--max-spots", type=positive_int, default=150, metavar="N",
                        help="keep the N brightest spots per image (default 150)")
    parser.add_argument("--centroid-sigma-floor", type=positive_float, default=0.3, metavar="PX",
                        help="added in quadrature to every spot's 1-sigma in the fit, smallest matching 1-sigma "
                             "[px] (default 0.3)")
    parser.add_argument("--max-time", type=positive_float, default=0.5, metavar="S",
                        help="time budget of one identification attempt [s] (default 0.5)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    parser.set_defaults(func=run)


def file_images(paths: list[str]):
    """(label, grey pixels, description) of each image file, read as `solve` reads it."""
    from .images import read_image

    for path in paths:
        image = read_image(path)
        yield str(path), image.pixels, image.description


def bag_images(path: str, topic: str, every: int, max_images: int):
    """
    (label 'BAG@STAMP_NS', pixels, description) of every `every`-th sensor_msgs/Image on `topic` of a bag.

    At most max_images; a message the centroider could not take is a BagError naming it
    (bags/validate.py).
    """
    from ..bags.format import IMAGE_ENCODINGS, IMAGE_TYPE, typestore
    from ..bags.reader import BagReader
    from ..bags.validate import image_problem

    with BagReader(path) as reader:
        name = reader.select([topic])[0]
        if reader.info.topics[name].type != IMAGE_TYPE:
            raise BagError(f"{path}: topic {name} holds {reader.info.topics[name].type}, not {IMAGE_TYPE}")
        taken = 0
        for index, (_, stamp_ns, data) in enumerate(reader.messages([name])):
            if index % every or taken >= max_images:
                continue
            problem = image_problem(data)
            if problem:
                raise BagError(f"{path}: image {index} on {name}: {problem}")
            msg = typestore().deserialize_cdr(data, IMAGE_TYPE)
            size = IMAGE_ENCODINGS[msg.encoding]
            dtype = np.dtype(np.uint8 if size == 1 else np.uint16).newbyteorder(">" if msg.is_bigendian else "<")
            rows = np.frombuffer(bytes(msg.data), np.uint8).reshape(int(msg.height), int(msg.step))
            pixels = np.ascontiguousarray(rows[:, :int(msg.width) * size]).view(dtype).astype(dtype.newbyteorder("="))
            taken += 1
            yield f"{path}@{stamp_ns}", pixels, f"{msg.encoding} {msg.width}x{msg.height}"


def image_spots(pixels: np.ndarray, description: str, args: argparse.Namespace):
    """(spots, width, height) of one image, centroided as `solve` does with these options."""
    from ..centroid import extract_spots
    from .solve import centroid_config

    height, width = pixels.shape
    return extract_spots(pixels, centroid_config(pixels, description, args)), width, height


def calibration_yaml(calibration, camera_name: str, images: list[dict]) -> str:
    """
    Return the ROS camera calibration file of a CameraCalibration (plumb_bob).

    With its fit as comments and under `star_tracker_calibration` (ignored by ROS readers).
    """
    import yaml

    cam = calibration.camera
    k = [cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0]
    p = [cam.fx, 0.0, cam.cx, 0.0, 0.0, cam.fy, cam.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    document = {
        "image_width": int(cam.width), "image_height": int(cam.height), "camera_name": camera_name,
        "camera_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in k]},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": [float(v) for v in cam.distortion]},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]},
        "projection_matrix": {"rows": 3, "cols": 4, "data": [float(v) for v in p]},
        "star_tracker_calibration": {**calibration.as_dict(), "images": images},
    }
    fit = calibration.as_dict()
    header = [f"# star-tracker calibrate: one camera fitted over {len(images)} image(s), {fit['stars']} stars, "
              f"residual RMS {fit['residual_rms_px']:.3f} px",
              "# 1-sigma: " + ", ".join(f"{n} {fit['value'][n]:.6g} +-{fit['sigma'][n]:.2g}" for n in fit["fitted"])
              + (f"; not constrained (kept): {', '.join(fit['not_fitted'])}" if fit["not_fitted"] else "")]
    return "\n".join(header) + "\n" + yaml.safe_dump(document, sort_keys=False, default_flow_style=None)


@guarded(NAME, errors=(BagError,))
def run(args: argparse.Namespace) -> int:
    from ..models.camera_calibration import CalibrationConfig, CalibrationFrame, calibrate_camera
    from .solve import SolveOptions, solve_spots

    if args.fov is not None and not 0.5 <= args.fov <= 80.0:
        raise CommandError(f"--fov {args.fov} must be in [0.5, 80] deg")
    if not args.images and not args.bag:
        raise CommandError("give image files and/or --bag")
    start = load_camera_file(args.camera).camera if args.camera else None
    report = (lambda text: None) if args.quiet else (lambda text: print(f"calibrate: {text}", file=sys.stderr,
                                                                        flush=True))
    options = SolveOptions(fov_tolerance_pct=args.fov_tolerance, fov_step_pct=args.fov_step,
                           centroid_sigma_floor_px=args.centroid_sigma_floor, max_time_s=args.max_time)
    size = None
    solved = []  # (path, spots, SolveResult)
    summary = []
    sources = itertools.chain(file_images(args.images),
                              bag_images(args.bag, args.topic, args.every, args.max_images) if args.bag else ())
    names = []
    for path, pixels, description in sources:
        names.append(path)
        spots, width, height = image_spots(pixels, description, args)
        if size is None:
            size = (width, height)
            if start is not None and (start.width, start.height) != size:
                raise CommandError(f"{args.camera} describes a {start.width}x{start.height} px camera; {path} is "
                                   f"{width}x{height} px")
        elif (width, height) != size:
            raise CommandError(f"{path} is {width}x{height} px, {names[0]} {size[0]}x{size[1]} px: one camera, "
                               "one image size")
        result = solve_spots(spots, width, height, fov_deg=args.fov, camera=start, options=options)
        stars = int(result.identification.hip.size) if result.solved else 0
        report(f"{path}: {'solved, ' + str(stars) + ' stars' if result.solved else 'not solved'}")
        summary.append({"image": str(path), "solved": result.solved, "stars": stars})
        if result.solved:
            solved.append((path, spots, result))
    if not solved:
        print(json.dumps({"images": summary, "calibrated": False}, indent=1) if args.json
              else "NOT CALIBRATED: no image solved", flush=True)
        return 1
    config = CalibrationConfig(sigma_floor_px=args.centroid_sigma_floor)
    first = max(solved, key=lambda s: s[2].identification.hip.size)[2].camera
    frames = [CalibrationFrame.from_identification(spots, result.identification) for _, spots, result in solved]
    calibration = calibrate_camera(frames, first, config)
    # Identify every image once more with the joint camera (more stars match at the corners) and refit.
    again = [solve_spots(spots, *size, camera=calibration.camera, options=options) for _, spots, _ in solved]
    identifications = [new.identification if new.solved and new.identification.hip.size >= old.identification.hip.size
                       else old.identification for new, (_, _, old) in zip(again, solved)]
    frames = [CalibrationFrame.from_identification(spots, ident) for (_, spots, _),
              ident in zip(solved, identifications)]
    calibration = calibrate_camera(frames, calibration.camera, config)
    images = []
    for k, (path, _, _) in enumerate(solved):
        images.append({"image": str(path), "stars": int(np.count_nonzero(calibration.inliers[k])),
                       "matched": int(frames[k].size), "residual_rms_px": float(calibration.frame_rms_px[k])})
    Path(args.output).write_text(calibration_yaml(calibration, args.camera_name, images))
    fit = calibration.as_dict()
    if args.json:
        print(json.dumps({"calibrated": True, "output": str(args.output), "images": summary, "frames": images,
                          "camera": {"width": calibration.camera.width, "height": calibration.camera.height,
                                     "fx": calibration.camera.fx, "fy": calibration.camera.fy,
                                     "cx": calibration.camera.cx, "cy": calibration.camera.cy,
                                     "distortion": list(calibration.camera.distortion)},
                          "calibration": fit}, indent=1))
        return 0
    from .solve import calibration_summary

    lines = [f"{len(solved)} of {len(names)} image(s) solved; one camera fitted over {fit['stars']} stars",
             f"fit: {calibration_summary(fit)}", "", f"{'stars':>6} {'RMS [px]':>9}  image"]
    lines += [f"{i['stars']:6d} {i['residual_rms_px']:9.3f}  {i['image']}" for i in images]
    lines += [f"{'-':>6} {'-':>9}  {s['image']} (not solved)" for s in summary if not s["solved"]]
    lines.append(f"wrote {args.output}")
    print("\n".join(lines))
    return 0
