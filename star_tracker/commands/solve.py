"""`star-tracker solve IMAGE`: lost-in-space solve of an image file (ours or a real photograph).

centroid (extract_spots) -> identify (make_identifier, pattern database for the field) with
the nominal field of view, then, when that fails, with fields stepped outward through
+-tolerance; the focal length is then refined by least squares over the matched stars and
the image identified once more with it (more matches, the final attitude and covariance).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .camera_files import camera_summary, load_camera_file
from .common import (CommandError, add_parser, database_config_for, guarded, non_negative_float, positive_float,
                     positive_int)

NAME = "solve"
MAX_REFINE_ROUNDS = 5
ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi


# identify.ALGORITHMS without importing it (its numba kernels would slow every `star-tracker --help`);
# test_commands checks that the two agree.
ALGORITHM_NAMES = ("angle_pivot", "composite", "hybrid", "match_groups", "pyramid", "spherical_triangle")
DEFAULT_ALGORITHM = "hybrid"


def register(subparsers) -> None:
    parser = add_parser(
        subparsers, NAME, "lost-in-space solve of an image file (PNG/TIFF/FITS, 8/16-bit, real or rendered)",
        "Find the stars in an image file, identify them in the Hipparcos catalog without any attitude "
        "guess, and print the boresight RA/Dec/roll (ICRS, sensor frame of msg_docs: +x image right, +y "
        "image down, +z boresight; roll 0 = image up toward north), its 1-sigma uncertainty, and every "
        "matched star with its residual. Give the camera as an approximate horizontal field of view "
        "(--fov): the nominal value is tried first, then fields stepped outward within the "
        "--fov-tolerance range; the focal length is refined from the matched stars by least squares. Or give "
        "an exact camera (--camera). Colour images are converted to grey. Exit code 0: solved; 1: not "
        "solved; 2: bad input. Pattern databases are cached in $STAR_TRACKER_CACHE (default "
        "~/.cache/star_tracker); the first solve for a new field builds one.",
        "star-tracker solve frame.png --fov 15\n"
        "star-tracker solve photo.jpg --fov 8 --fov-tolerance 10 --plot solved.png --json > solution.json\n"
        "star-tracker solve frame.fits --camera config/star_tracker.yaml")
    parser.add_argument("image", help="image file: PNG, TIFF, JPEG (8 or 16-bit, grey or colour) or FITS "
                                      "(.fits/.fit, integer or float)")
    camera = parser.add_mutually_exclusive_group(required=True)
    camera.add_argument("--fov", type=positive_float, metavar="DEG",
                        help="approximate horizontal field of view [deg] (image width across; square pixels, "
                             "principal point at the centre, no distortion assumed)")
    camera.add_argument("--camera", metavar="YAML",
                        help="exact camera instead of --fov: camera_simulator parameters (image.width/height, "
                             "optics.fov_x_deg, optics.distortion, as config/star_tracker.yaml) or a ROS camera "
                             "calibration file (camera_matrix, distortion_coefficients)")
    parser.add_argument("--fov-tolerance", type=non_negative_float, default=5.0, metavar="PCT",
                        help="with --fov: search fields within +-PCT percent of it when the nominal one fails "
                             "(default 5; 0 = nominal only)")
    parser.add_argument("--fov-step", type=positive_float, default=0.5, metavar="PCT",
                        help="step of that search [percent] (default 0.5; a solve needs the field within "
                             "~0.3 %% on real photographs)")
    parser.add_argument("--no-refine", action="store_true",
                        help="keep the given/searched focal length (default: refine it by least squares over "
                             "the matched stars when --fov is used)")
    parser.add_argument("--algorithm", choices=ALGORITHM_NAMES, default=DEFAULT_ALGORITHM,
                        help=f"identification algorithm (default {DEFAULT_ALGORITHM}; docs/IDENTIFICATION.md)")
    parser.add_argument("--detection-sigma", type=positive_float, default=4.5, metavar="K",
                        help="detection threshold in noise sigmas of the PSF-matched image (default 4.5)")
    parser.add_argument("--psf-sigma", type=non_negative_float, default=None, metavar="PX",
                        help="fix the optics' PSF 1-sigma [px] for the centroid fit and the hot-pixel/cosmic-ray "
                             "shape test (default: estimated from the image's stars, prior 1.0; 0 = no shape "
                             "test, centre of gravity)")
    parser.add_argument("--max-spots", type=positive_int, default=150, metavar="N",
                        help="keep the N brightest spots (default 150: a deep photograph has thousands of stars "
                             "fainter than the catalog)")
    parser.add_argument("--magnitude-limit", type=positive_float, default=None, metavar="HP",
                        help="faintest guide star of the pattern database [Hp mag] (default: 6.5, fainter for "
                             "fields narrower than ~7 deg, at most 8)")
    parser.add_argument("--epoch", type=positive_float, default=2026.0, metavar="YEAR",
                        help="catalog epoch for proper motion [Julian year] (default 2026.0)")
    parser.add_argument("--centroid-sigma-floor", type=positive_float, default=0.3, metavar="PX",
                        help="smallest spot position 1-sigma used for matching [px] (default 0.3: real optics "
                             "and JPEG/8-bit quantisation; the attitude fit weights use the centroider's own "
                             "covariance)")
    parser.add_argument("--max-time", type=positive_float, default=0.5, metavar="S",
                        help="time budget of one identification attempt [s] (default 0.5; the final attempt with "
                             "the refined focal length gets 4x)")
    parser.add_argument("--json", action="store_true", help="print the solution as JSON instead of text")
    parser.add_argument("--plot", metavar="PNG",
                        help="write the image annotated with the identified stars (HIP ids, residual vectors "
                             "magnified), unmatched spots marked")
    parser.add_argument("--residual-scale", type=positive_float, default=None, metavar="X",
                        help="magnification of the residual vectors in --plot (default: the median residual "
                             "drawn as ~15 px)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    parser.set_defaults(func=run)


@dataclass(frozen=True)
class SolveOptions:
    """Knobs of solve_spots (the CLI options; angles in percent where named so)."""

    algorithm: str = "hybrid"
    fov_tolerance_pct: float = 5.0
    fov_step_pct: float = 0.5
    refine_focal: bool = True
    centroid_sigma_floor_px: float = 0.3
    max_time_s: float = 0.5
    magnitude_limit: float | None = None
    epoch_jyear: float = 2026.0


@dataclass
class SolveResult:
    """identification: the final Identification (None when nothing solved); camera: the camera
    it refers to (refined focal length); focal_sigma_px: 1-sigma of the refined focal length
    [px] (None when not refined); attempts: one dict per identification attempt."""

    identification: object | None
    camera: object
    database: object
    attempts: list = field(default_factory=list)
    focal_sigma_px: float | None = None

    @property
    def solved(self) -> bool:
        return self.identification is not None and self.identification.solved


def fov_candidates(fov_deg: float, tolerance_pct: float, step_pct: float) -> list[float]:
    """The nominal field, then fields stepped outward alternately above and below it, within
    +-tolerance_pct percent (the bounds included)."""
    steps = int(math.floor(tolerance_pct / step_pct + 1e-9))
    values = [fov_deg]
    for k in range(1, steps + 1):
        values += [fov_deg * (1 + k * step_pct / 100.0), fov_deg * (1 - k * step_pct / 100.0)]
    if steps * step_pct < tolerance_pct - 1e-9:
        values += [fov_deg * (1 + tolerance_pct / 100.0), fov_deg * (1 - tolerance_pct / 100.0)]
    return values


def camera_for_fov(width: int, height: int, fov_deg: float):
    from ..models.camera import CameraModel

    return CameraModel.from_fov(width, height, math.radians(fov_deg))


def solve_spots(spots, width: int, height: int, fov_deg: float | None = None, camera=None,
                options: SolveOptions = SolveOptions(), report=None) -> SolveResult:
    """Identify `spots` of a width x height image: with `camera` exactly, or with a pinhole of
    horizontal field fov_deg [deg], searched within the tolerance (see the module docstring).
    `report(text)` receives one progress line per attempt after the first."""
    from ..identify import IdentifyConfig, load_or_build_database, make_identifier

    if (fov_deg is None) == (camera is None):
        raise ValueError("give exactly one of fov_deg and camera")
    nominal = camera if camera is not None else camera_for_fov(width, height, fov_deg)
    fov_x = 2.0 * math.atan(0.5 * nominal.width / nominal.fx)
    db_config = database_config_for(fov_x, nominal.width, nominal.height, options.magnitude_limit, options.epoch_jyear)
    database = load_or_build_database(db_config)
    config = IdentifyConfig(centroid_sigma_floor_px=options.centroid_sigma_floor_px, max_time_s=options.max_time_s)
    identifier = make_identifier(options.algorithm, database, config)
    if hasattr(identifier, "warm_up"):
        identifier.warm_up(nominal)  # compile/load the kernels outside the time budget
    candidates = [nominal] if camera is not None else [
        camera_for_fov(width, height, f) for f in fov_candidates(fov_deg, options.fov_tolerance_pct, options.fov_step_pct)]
    result = SolveResult(None, nominal, database)
    for index, trial in enumerate(candidates):
        budget = options.max_time_s if hasattr(identifier, "warm_up") or index else max(options.max_time_s, 20.0)
        identifier.config = replace(config, max_time_s=budget)
        started = time.perf_counter()
        identification = identifier.identify(spots, trial)
        trial_fov = math.degrees(2.0 * math.atan(0.5 * trial.width / trial.fx))
        result.attempts.append({"fov_x_deg": trial_fov, "status": identification.status,
                                "elapsed_s": round(time.perf_counter() - started, 3)})
        if report is not None and (index or not identification.solved):
            report(f"FOV {trial_fov:.4f} deg: {identification.status} ({time.perf_counter() - started:.2f} s)"
                   f"  [{index + 1}/{len(candidates)}]")
        if identification.solved:
            result.identification, result.camera = identification, trial
            break
    if not result.solved or camera is not None or not options.refine_focal:
        return result
    # A first solve may hold only a few stars near the centre (the rest fell outside the match
    # radius at the wrong scale): refine, identify again with more stars, until none are added.
    identifier.config = replace(config, max_time_s=4.0 * options.max_time_s)
    for round_index in range(MAX_REFINE_ROUNDS):
        refined, sigma_f = refine_focal_length(result.camera, spots, result.identification)
        started = time.perf_counter()
        final = identifier.identify(spots, refined)
        result.attempts.append({"fov_x_deg": math.degrees(2.0 * math.atan(0.5 * refined.width / refined.fx)),
                                "status": final.status, "elapsed_s": round(time.perf_counter() - started, 3),
                                "refined": True, "stars": int(final.hip.size)})
        grew = final.solved and final.hip.size > result.identification.hip.size
        if final.solved and (grew or round_index == 0 and final.hip.size == result.identification.hip.size):
            result.identification, result.camera, result.focal_sigma_px = final, refined, sigma_f
        if not grew:
            break
    return result


def refine_focal_length(camera, spots, identification):
    """Least-squares focal length (fx = fy, principal point kept) and attitude over the matched
    stars, minimising pixel residuals. Returns the camera with it and its 1-sigma [px]."""
    from scipy.optimize import least_squares

    from ..models.attitude import rotation_vector_to_matrix
    from ..models.camera import CameraModel

    x = spots.x[identification.spot_index]
    y = spots.y[identification.spot_index]
    stars = identification.star_vectors
    rotation0 = identification.attitude.rotation

    def residuals(params):
        rotation = rotation0 @ rotation_vector_to_matrix(params[:3])
        scale = math.exp(params[3])
        trial = replace_focal(camera, camera.fx * scale, camera.fy * scale)
        u, v, _ = trial.project(stars @ rotation)
        return np.concatenate([u - x, v - y])

    def replace_focal(cam, fx, fy):
        return CameraModel(cam.width, cam.height, fx, fy, cam.cx, cam.cy, tuple(cam.distortion))

    fit = least_squares(residuals, np.zeros(4), method="lm")
    scale = math.exp(fit.x[3])
    dof = max(fit.fun.size - 4, 1)
    variance = float(np.sum(fit.fun ** 2)) / dof
    try:
        covariance = np.linalg.inv(fit.jac.T @ fit.jac) * variance
        sigma_f = math.sqrt(max(covariance[3, 3], 0.0)) * camera.fx * scale
    except np.linalg.LinAlgError:
        sigma_f = float("nan")
    return replace_focal(camera, camera.fx * scale, camera.fy * scale), sigma_f


def solution_record(result: SolveResult, spots, image_path: str, description: str) -> dict:
    """Everything `solve` prints, as plain values (the --json document)."""
    from ..models.attitude import matrix_to_radec_roll

    cam = result.camera
    record = {"image": image_path, "image_description": description, "spots": int(len(spots)),
              "solved": result.solved, "attempts": result.attempts,
              "camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
                         "cy": cam.cy, "distortion": list(cam.distortion),
                         "fov_x_deg": math.degrees(2.0 * math.atan(0.5 * cam.width / cam.fx)),
                         "focal_sigma_px": result.focal_sigma_px},
              "database": {"magnitude_limit": result.database.config.magnitude_limit,
                           "max_pair_angle_deg": math.degrees(result.database.config.max_pair_angle_rad),
                           "epoch_jyear": result.database.config.epoch_jyear, "stars": result.database.star_count}}
    psf = getattr(spots, "psf", None)
    if psf is not None:
        record["psf"] = {"sigma_px": psf.sigma_px, "sigma_major_px": psf.sigma_major_px,
                         "sigma_minor_px": psf.sigma_minor_px, "angle_deg": math.degrees(psf.angle_rad),
                         "sigma_uncertainty_px": None if math.isnan(psf.sigma_uncertainty_px)
                         else psf.sigma_uncertainty_px, "stars": psf.stars, "source": psf.source,
                         "reason": psf.reason, "applied_sigma_px": psf.applied_sigma_px}
    ident = result.identification
    if ident is None:
        return record
    record.update({"status": ident.status, "reason": ident.reason, "algorithm": ident.algorithm})
    if not ident.solved:
        return record
    rotation = ident.attitude.rotation
    ra, dec, roll = (math.degrees(a) for a in matrix_to_radec_roll(rotation))
    sigma = np.sqrt(np.maximum(np.diag(ident.attitude.covariance), 0.0)) * ARCSEC_PER_RAD
    by_hip = np.argsort(result.database.hip)
    where = by_hip[np.searchsorted(result.database.hip, ident.hip, sorter=by_hip)]
    magnitude = result.database.magnitude[where]
    predicted_x, predicted_y, _ = cam.project(ident.star_vectors @ rotation)
    matched = []
    for k in range(ident.hip.size):
        spot = int(ident.spot_index[k])
        matched.append({"hip": int(ident.hip[k]), "magnitude": round(float(magnitude[k]), 3),
                        "x": round(float(spots.x[spot]), 3), "y": round(float(spots.y[spot]), 3),
                        "predicted_x": round(float(predicted_x[k]), 3), "predicted_y": round(float(predicted_y[k]), 3),
                        "residual_arcsec": round(float(ident.residual_rad[k]) * ARCSEC_PER_RAD, 3),
                        "flux": round(float(spots.flux[spot]), 2)})
    matched.sort(key=lambda m: m["magnitude"])
    record.update({
        "ra_deg": ra, "dec_deg": dec, "roll_deg": roll,
        "quaternion_xyzw": [float(q) for q in ident.attitude.quaternion],
        "sigma_arcsec": {"x": float(sigma[0]), "y": float(sigma[1]), "roll": float(sigma[2]),
                         "cross_boresight": float(math.hypot(sigma[0], sigma[1]))},
        "covariance_rad2": ident.attitude.covariance.tolist(),
        "false_positive_bound": float(ident.false_positive_probability),
        "matched": matched,
        "residual_rms_arcsec": float(np.sqrt(np.mean((ident.residual_rad * ARCSEC_PER_RAD) ** 2))),
    })
    return record


def format_text(record: dict) -> str:
    lines = [f"image: {record['image']} ({record['image_description']}), {record['spots']} spots",
             f"camera: {camera_summary_from(record['camera'])}"
             + (f", focal length +-{record['camera']['focal_sigma_px']:.2f} px (refined)"
                if record['camera'].get('focal_sigma_px') is not None else "")]
    if record.get("psf"):
        lines.append(f"psf: {psf_summary(record['psf'])}")
    if not record["solved"]:
        lines.append(f"NOT SOLVED: {record.get('reason', 'no attempt')} "
                     f"({len(record['attempts'])} attempt(s), fields "
                     f"{min(a['fov_x_deg'] for a in record['attempts']):.3f}-"
                     f"{max(a['fov_x_deg'] for a in record['attempts']):.3f} deg)")
        return "\n".join(lines)
    s = record["sigma_arcsec"]
    q = record["quaternion_xyzw"]
    lines += [
        f"solved: {record['reason']} ({record['algorithm']})",
        f"RA {record['ra_deg']:.5f} deg  Dec {record['dec_deg']:+.5f} deg  roll {record['roll_deg']:+.4f} deg",
        f"quaternion (x, y, z, w) sensor->ICRS: {q[0]:+.8f} {q[1]:+.8f} {q[2]:+.8f} {q[3]:+.8f}",
        f"1-sigma: cross-boresight {s['cross_boresight']:.2f}\" (x {s['x']:.2f}\", y {s['y']:.2f}\"), roll {s['roll']:.2f}\"",
        f"residual RMS {record['residual_rms_arcsec']:.2f}\" over {len(record['matched'])} stars",
        "",
        f"{'HIP':>7} {'Hp':>6} {'x [px]':>9} {'y [px]':>9} {'residual':>9}",
    ]
    for m in record["matched"]:
        lines.append(f"{m['hip']:7d} {m['magnitude']:6.2f} {m['x']:9.2f} {m['y']:9.2f} {m['residual_arcsec']:8.2f}\"")
    return "\n".join(lines)


def psf_summary(psf: dict) -> str:
    """One line on the PSF the centroider used (solution_record's "psf")."""
    if psf["source"] == "estimated":
        text = (f"sigma {psf['sigma_px']:.2f} +-{psf['sigma_uncertainty_px']:.2f} px estimated from {psf['stars']} "
                f"stars (major {psf['sigma_major_px']:.2f}, minor {psf['sigma_minor_px']:.2f} px at "
                f"{psf['angle_deg']:+.0f} deg)")
        return text + (f", measured with the prior {psf['applied_sigma_px']:.2f} px"
                       if psf["applied_sigma_px"] != psf["sigma_px"] else "")
    if psf["source"] == "prior":
        return f"sigma {psf['sigma_px']:.2f} px (the prior: {psf['reason']})"
    return f"sigma {psf['sigma_px']:.2f} px (fixed)" if psf["sigma_px"] > 0 else "none (centre of gravity)"


def camera_summary_from(camera: dict) -> str:
    from ..models.camera import CameraModel

    return camera_summary(CameraModel(camera["width"], camera["height"], camera["fx"], camera["fy"], camera["cx"],
                                      camera["cy"], tuple(camera["distortion"])))


@guarded(NAME)
def run(args: argparse.Namespace) -> int:
    from ..centroid import CentroidConfig, extract_spots
    from .images import read_image

    image = read_image(args.image)
    height, width = image.pixels.shape
    camera = None
    if args.camera:
        camera = load_camera_file(args.camera).camera
        if (camera.width, camera.height) != (width, height):
            raise CommandError(f"{args.camera} describes a {camera.width}x{camera.height} px camera; "
                               f"{args.image} is {width}x{height} px")
    if args.fov is not None and not 0.5 <= args.fov <= 80.0:
        raise CommandError(f"--fov {args.fov} must be in [0.5, 80] deg")
    if args.fov is not None and args.fov_tolerance >= 50.0:
        raise CommandError(f"--fov-tolerance {args.fov_tolerance} must be < 50 percent")
    pixels = image.pixels
    saturation = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(pixels.dtype, 0.0)
    if "8-bit" in image.description and pixels.dtype.kind == "f":
        saturation = 255.0  # colour 8-bit averaged to float grey
    config = CentroidConfig(detection_sigma=args.detection_sigma,
                            psf_sigma_px=1.0 if args.psf_sigma is None else args.psf_sigma,
                            psf_mode="auto" if args.psf_sigma is None else "fixed",
                            method="cog" if args.psf_sigma == 0 else "auto", max_spots=args.max_spots,
                            saturation_adu=saturation)
    spots = extract_spots(pixels, config)
    report = None if args.quiet else (lambda text: print(f"solve: {text}", file=sys.stderr, flush=True))
    options = SolveOptions(algorithm=args.algorithm, fov_tolerance_pct=args.fov_tolerance,
                           fov_step_pct=args.fov_step, refine_focal=not args.no_refine,
                           centroid_sigma_floor_px=args.centroid_sigma_floor, max_time_s=args.max_time,
                           magnitude_limit=args.magnitude_limit, epoch_jyear=args.epoch)
    result = solve_spots(spots, width, height, fov_deg=args.fov, camera=camera, options=options, report=report)
    record = solution_record(result, spots, str(args.image), image.description)
    if args.plot:
        from ..visualize import save_solution_plot

        save_solution_plot(args.plot, pixels, record, spots, residual_scale=args.residual_scale)
        record["plot"] = str(args.plot)
    if args.json:
        print(json.dumps(record, indent=1))
    else:
        print(format_text(record))
        if args.plot:
            print(f"wrote {args.plot}")
    return 0 if result.solved else 1
