# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker solve IMAGE`: lost-in-space solve of an image file (ours or a real photograph).

centroid (extract_spots) -> identify (make_identifier, pattern database for the field) with
the nominal field of view, then, when that fails, with fields stepped outward through
+-tolerance; the camera is then refined by least squares over the matched stars (focal
length; k1, k2 and the principal point where the stars constrain them:
models/camera_calibration.py) and the image identified once more with it (more matches, the
final attitude and covariance). The reported attitude is that of the image centre pixel.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np

from .camera_files import camera_summary, load_camera_file
from .common import (CommandError, add_parser, database_config_for, guarded, non_negative_float, positive_float,
                     positive_int)

NAME = "solve"
MAX_REFINE_ROUNDS = 5
MARGINAL_LOSS = 0.02  # share of the matched stars a refined camera fitted to more stars may lose
ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi


# identify.ALGORITHMS without importing it (its numba kernels would slow every `star-tracker --help`);
# test_commands checks that the two agree.
FIELD_SEARCHES = ("patterns", "steps", "both")
DEFAULT_FIELD_SEARCH = "both"
PATTERN_SEARCH_BUDGET_S = 1.5  # CPU time for the scale-free pattern search
DEFAULT_STEP_SEARCH_TIME_S = 1.5  # CPU time shared by the stepped fields (a fallback: say "not solved" soon)

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
    parser.add_argument("--field-search", choices=FIELD_SEARCHES, default=DEFAULT_FIELD_SEARCH,
                        help="how the field is found within the tolerance: 'patterns' = four-star patterns "
                             "matched by shape alone give the focal length (fast, and a frame that cannot be "
                             "solved says so quickly); 'steps' = identify at fields stepped by --fov-step; "
                             f"'both' = patterns first, then steps (default {DEFAULT_FIELD_SEARCH})")
    parser.add_argument("--step-search-time", type=positive_float, default=DEFAULT_STEP_SEARCH_TIME_S, metavar="S",
                        help="CPU time shared by the stepped fields of --field-search steps/both [s] (default "
                             f"{DEFAULT_STEP_SEARCH_TIME_S:g}: each field gets its share, at most --max-time; the "
                             "pattern search finds the field of most frames, and an unsolvable frame says so soon)")
    parser.add_argument("--no-refine", action="store_true",
                        help="keep the given/searched camera (default with --fov: refine its focal length and, "
                             "where the stars constrain them, k1, k2 and the principal point by least squares over "
                             "the matched stars)")
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
                             "fields narrower than ~12 deg so that a sparse sky still holds ~8 in view, at most 8)")
    parser.add_argument("--epoch", type=positive_float, default=2026.0, metavar="YEAR",
                        help="catalog epoch for proper motion [Julian year] (default 2026.0)")
    parser.add_argument("--centroid-sigma-floor", type=positive_float, default=0.3, metavar="PX",
                        help="smallest spot position 1-sigma used for matching [px] (default 0.3: real optics "
                             "and JPEG/8-bit quantisation; the attitude fit weights use the centroider's own "
                             "covariance)")
    parser.add_argument("--max-time", type=positive_float, default=0.5, metavar="S",
                        help="time budget of one identification attempt [s of CPU time, so that a loaded host "
                             "gives the same result] (default 0.5; the final attempt with the refined focal "
                             "length gets 4x)")
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
    field_search: str = DEFAULT_FIELD_SEARCH
    fov_step_pct: float = 0.5
    step_search_time_s: float = DEFAULT_STEP_SEARCH_TIME_S
    refine_focal: bool = True
    centroid_sigma_floor_px: float = 0.3
    max_time_s: float = 0.5
    magnitude_limit: float | None = None
    epoch_jyear: float = 2026.0


@dataclass
class SolveResult:
    """
    identification: the final Identification (None when nothing solved).

    Camera: the camera it refers to (refined focal length and distortion); focal_sigma_px:
    1-sigma of the refined focal length [px] (None when not refined); calibration: the
    CameraCalibration of that refinement (models/camera_calibration.py; None when not
    refined); attempts: one dict per identification attempt.
    """

    identification: object | None
    camera: object
    database: object
    attempts: list = field(default_factory=list)
    focal_sigma_px: float | None = None
    calibration: object | None = None

    @property
    def solved(self) -> bool:
        return self.identification is not None and self.identification.solved


def fov_candidates(fov_deg: float, tolerance_pct: float, step_pct: float) -> list[float]:
    """
    Return the nominal field, then fields stepped outward alternately above and below it.

    Within +-tolerance_pct percent (the bounds included).
    """
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
    """
    Identify `spots` of a width x height image.

    With `camera` exactly, or with a pinhole of horizontal field fov_deg [deg], searched
    within the tolerance (see the module docstring). `report(text)` receives one progress line
    per attempt after the first.
    """
    from ..identify import IdentifyConfig, load_or_build_database, make_identifier
    from ..identify.base import TOO_FEW_SPOTS

    if (fov_deg is None) == (camera is None):
        raise ValueError("give exactly one of fov_deg and camera")
    nominal = camera if camera is not None else camera_for_fov(width, height, fov_deg)
    fov_x = 2.0 * math.atan(0.5 * nominal.width / nominal.fx)
    db_config = database_config_for(fov_x, nominal.width, nominal.height, options.magnitude_limit, options.epoch_jyear)
    database = load_or_build_database(db_config)
    # An offline solve counts its budget in CPU time: the same attempts succeed on a busy host.
    config = IdentifyConfig(centroid_sigma_floor_px=options.centroid_sigma_floor_px, max_time_s=options.max_time_s,
                            budget_clock="cpu")
    identifier = make_identifier(options.algorithm, database, config)
    if hasattr(identifier, "warm_up"):
        identifier.warm_up(nominal)  # compile/load the kernels outside the time budget
    result = SolveResult(None, nominal, database)
    candidates = [(nominal, False, None)] if camera is not None else field_candidates(
        spots, nominal, database, fov_deg, options, result.attempts)
    steps = sum(stepped for _, stepped, _ in candidates)
    step_budget = min(options.max_time_s, options.step_search_time_s / steps) if steps else options.max_time_s
    for index, (trial, stepped, rotation) in enumerate(candidates):
        budget = step_budget if stepped else options.max_time_s
        if index == 0 and not hasattr(identifier, "warm_up"):
            budget = max(budget, 20.0)  # its kernels compile in the first attempt
        identifier.config = replace(config, max_time_s=budget)
        started = time.perf_counter()
        # A pattern match's own attitude is verified first (verify_hypothesis: the false-positive
        # bound applies); the search runs only when it fails.
        identification = (identifier.identify(spots, trial) if rotation is None
                          else identifier.identify_near(spots, trial, rotation))
        trial_fov = math.degrees(2.0 * math.atan(0.5 * trial.width / trial.fx))
        result.attempts.append({"fov_x_deg": trial_fov, "status": identification.status,
                                "elapsed_s": round(time.perf_counter() - started, 3), "budget_s": budget,
                                "hypotheses": identification.hypotheses}
                               | ({"stepped": True} if stepped else {}))
        if report is not None and (index or not identification.solved):
            report(f"FOV {trial_fov:.4f} deg: {identification.status} ({time.perf_counter() - started:.2f} s)"
                   f"  [{index + 1}/{len(candidates)}]")
        if identification.solved:
            result.identification, result.camera = identification, trial
            break
        if identification.status == TOO_FEW_SPOTS:
            break  # no field can help: the spots are too few whatever the scale
    if not result.solved or camera is not None or not options.refine_focal:
        return result
    # A first solve may hold only a few stars near the centre (the rest fell outside the match
    # radius at the wrong scale): refine, identify again with more stars, until none are added
    # (near the attitude fitted with the camera: its stars match without a search).
    identifier.config = replace(config, max_time_s=4.0 * options.max_time_s)
    for round_index in range(MAX_REFINE_ROUNDS):
        try:
            calibration = refine_camera(result.camera, spots, result.identification, options.centroid_sigma_floor_px)
        except ValueError:  # too few stars to fit even the focal length: keep the searched camera
            break
        refined = calibration.camera
        started = time.perf_counter()
        final = identifier.identify_near(spots, refined, calibration.rotations[0])
        result.attempts.append({"fov_x_deg": math.degrees(2.0 * math.atan(0.5 * refined.width / refined.fx)),
                                "status": final.status, "elapsed_s": round(time.perf_counter() - started, 3),
                                "refined": True, "stars": int(final.hip.size), "fitted": list(calibration.fitted)})
        grew = final.solved and final.hip.size > result.identification.hip.size
        # As many stars: keep the camera fitted to the most stars (the one reported with them).
        # A camera fitted to more stars than the kept one's is kept too when its identification
        # lost only a marginal match or two: else a camera fitted to a first, smaller star set is
        # reported with the larger one found through it.
        # So is one whose identification lost more when the kept camera was fitted to fewer stars
        # than it is reported with (a first solve's, through which more were found): the new
        # camera is fitted to those, and keeps at least as many.
        fitted_to_more = result.calibration is None or calibration.stars > result.calibration.stars
        kept = result.identification.hip.size
        outgrown = result.calibration is not None and result.calibration.stars < kept
        if final.solved and (final.hip.size >= kept
                             or fitted_to_more and final.hip.size >= kept - max(1, round(MARGINAL_LOSS * kept))
                             or fitted_to_more and outgrown and final.hip.size >= result.calibration.stars):
            result.identification, result.camera, result.calibration = final, refined, calibration
            result.focal_sigma_px = calibration.sigma["f"]
        if not grew:
            break
    return result


def field_candidates(spots, nominal, database, fov_deg: float, options: SolveOptions, attempts: list) -> list:
    """
    (camera, stepped, rotation) to identify at, in order.

    The focal lengths of scale-free pattern matches with their attitudes (identify/scale_free.py;
    the search is appended to `attempts`), then (field_search steps/both) the stepped fields
    (stepped True: they share options.step_search_time_s; rotation None).
    """
    from ..identify.deadline import Deadline
    from ..identify.scale_free import estimate_fields, load_or_build_patterns

    cameras = []
    if options.field_search in ("patterns", "both"):
        tolerance = options.fov_tolerance_pct / 100.0
        short_side_rad = 2.0 * math.atan(0.5 * min(nominal.width / nominal.fx, nominal.height / nominal.fy))
        patterns = load_or_build_patterns(database, 0.5 * short_side_rad * (1.0 - tolerance))
        started = time.perf_counter()
        estimates = estimate_fields(spots, nominal, database, patterns, tolerance,
                                    Deadline(PATTERN_SEARCH_BUDGET_S, "cpu"))
        attempts.append({"fov_x_deg": fov_deg, "search": "patterns",
                         "elapsed_s": round(time.perf_counter() - started, 3),
                         "status": f"{len(estimates)} field(s) found" if estimates else "no pattern matched",
                         "fields_deg": [round(math.degrees(2.0 * math.atan(0.5 * e.camera.width / e.camera.fx)), 4)
                                        for e in estimates]})
        cameras += [(estimate.camera, False, estimate.rotation) for estimate in estimates]
    if options.field_search in ("steps", "both"):
        cameras += [(camera_for_fov(nominal.width, nominal.height, f), True, None)
                    for f in fov_candidates(fov_deg, options.fov_tolerance_pct, options.fov_step_pct)]
    return cameras


def refine_camera(camera, spots, identification, sigma_floor_px: float):
    """
    Fit the camera and attitude by least squares over the matched stars.

    Pixel residuals weighted by the spots' covariances, sigma_floor_px [px] added in
    quadrature: the focal length (fx, fy scaled together), and k1, k2 and the principal point
    where the stars constrain them (models/camera_calibration.py). Returns the
    CameraCalibration; ValueError with < 3 stars.
    """
    from ..models.camera_calibration import CalibrationConfig, CalibrationFrame, calibrate_camera

    frame = CalibrationFrame.from_identification(spots, identification)
    return calibrate_camera([frame], camera, CalibrationConfig(sigma_floor_px=sigma_floor_px))


def image_centre_rotation(rotation: np.ndarray, camera) -> np.ndarray:
    """
    Return the sensor -> ICRS rotation of the frame whose +z passes through the image centre pixel ((W-1)/2, (H-1)/2).

    `rotation` (the camera frame, +z through the principal point) turned by the smallest
    rotation that takes +z to that pixel's ray. The identity turn when the principal point is
    the image centre.
    """
    from ..models.attitude import rotation_vector_to_matrix

    centre = camera.pixel_to_ray(np.array([(camera.width - 1) / 2.0]), np.array([(camera.height - 1) / 2.0]))[0]
    axis = np.cross([0.0, 0.0, 1.0], centre)
    sine = float(np.linalg.norm(axis))
    if sine < 1e-15:
        return rotation
    return rotation @ rotation_vector_to_matrix(axis / sine * math.atan2(sine, float(centre[2])))


def solution_record(result: SolveResult, spots, image_path: str, description: str) -> dict:
    """Everything `solve` prints, as plain values (the --json document)."""
    from ..models.attitude import matrix_to_quaternion, matrix_to_radec_roll

    cam = result.camera
    record = {"image": image_path, "image_description": description, "spots": int(len(spots)),
              "spots_rejected_shape": int(getattr(spots, "rejected_shape", 0)),
              "spots_rejected_extended": int(getattr(spots, "rejected_extended", 0)),
              "solved": result.solved, "attempts": result.attempts,
              "camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
                         "cy": cam.cy, "distortion": list(cam.distortion),
                         "fov_x_deg": math.degrees(2.0 * math.atan(0.5 * cam.width / cam.fx)),
                         "focal_sigma_px": result.focal_sigma_px,
                         "calibration": None if result.calibration is None else result.calibration.as_dict()},
              "database": {"magnitude_limit": result.database.config.magnitude_limit,
                           "max_pair_angle_deg": math.degrees(result.database.config.max_pair_angle_rad),
                           "epoch_jyear": result.database.config.epoch_jyear, "stars": result.database.star_count}}
    psf = getattr(spots, "psf", None)
    if psf is not None:
        record["psf"] = {"sigma_px": psf.sigma_px, "sigma_major_px": psf.sigma_major_px,
                         "sigma_minor_px": psf.sigma_minor_px, "angle_deg": math.degrees(psf.angle_rad),
                         "sigma_uncertainty_px": None if math.isnan(psf.sigma_uncertainty_px)
                         else psf.sigma_uncertainty_px, "stars": psf.stars, "source": psf.source,
                         "reason": psf.reason, "applied_sigma_px": psf.applied_sigma_px, "annular": psf.annular,
                         "fit_model": getattr(spots, "fit_model", "")}
    ident = result.identification
    if ident is None:
        record.update(unsolved_summary(result.attempts))
        return record
    record.update({"status": ident.status, "reason": ident.reason, "algorithm": ident.algorithm})
    if not ident.solved:
        return record
    rotation = ident.attitude.rotation
    # The reported boresight is the image centre pixel's (a fitted principal point may lie elsewhere).
    centred = image_centre_rotation(rotation, cam)
    turn = rotation.T @ centred
    covariance = turn.T @ ident.attitude.covariance @ turn
    ra, dec, roll = (math.degrees(a) for a in matrix_to_radec_roll(centred))
    sigma = np.sqrt(np.maximum(np.diag(covariance), 0.0)) * ARCSEC_PER_RAD
    magnitude = ident.magnitude  # guide or deep catalog Hp
    predicted_x, predicted_y, _ = cam.project(ident.star_vectors @ rotation)
    spot = ident.spot_index
    # The spot's own 1-sigma (largest axis of its covariance) and flags (msg_docs/spots.md: 1
    # saturated, 4 streak, 8 blended, ...).
    sigma_px = np.sqrt(np.linalg.eigvalsh(spots.cov[spot])[:, -1]) if spot.size else np.zeros(0)
    columns = zip(ident.hip.tolist(), magnitude.tolist(), spots.x[spot].tolist(), spots.y[spot].tolist(),
                  predicted_x.tolist(), predicted_y.tolist(), (ident.residual_rad * ARCSEC_PER_RAD).tolist(),
                  spots.flux[spot].tolist(), ident.deep.tolist(), sigma_px.tolist(), spots.flags[spot].tolist())
    matched = [{"hip": int(hip), "magnitude": round(mag, 3), "x": round(x, 3), "y": round(y, 3),
                "predicted_x": round(px, 3), "predicted_y": round(py, 3), "residual_arcsec": round(res, 3),
                "flux": round(flux, 2), "deep": bool(deep), "sigma_px": round(sig, 4), "flags": int(flags)}
               for hip, mag, x, y, px, py, res, flux, deep, sig, flags in columns]
    matched.sort(key=lambda m: m["magnitude"])
    record.update({
        "ra_deg": ra, "dec_deg": dec, "roll_deg": roll,
        "quaternion_xyzw": [float(q) for q in (ident.attitude.quaternion if centred is rotation
                                               else matrix_to_quaternion(centred))],
        "sigma_arcsec": {"x": float(sigma[0]), "y": float(sigma[1]), "roll": float(sigma[2]),
                         "cross_boresight": float(math.hypot(sigma[0], sigma[1]))},
        "covariance_rad2": covariance.tolist(),
        "false_positive_bound": float(ident.false_positive_probability),
        "matched": matched,
        "deep_matched": ident.deep_count,  # of `matched`, stars from the deep catalog (not guide stars)
        "residual_rms_arcsec": float(np.sqrt(np.mean((ident.residual_rad * ARCSEC_PER_RAD) ** 2))),
    })
    return record


def unsolved_summary(attempts: list[dict]) -> dict:
    """Return status "not_solved" and a reason naming what was tried and how each attempt ended."""
    searches = [a for a in attempts if a.get("search") == "patterns"]
    identifications = [a for a in attempts if a.get("search") != "patterns"]
    parts = []
    if searches and not searches[-1]["fields_deg"]:
        parts.append("no four-star pattern of the brightest spots matched the sky at a field within the tolerance")
    if identifications:
        fields = [a["fov_x_deg"] for a in identifications]
        outcomes = Counter(a["status"] for a in identifications)
        ended = ", ".join(f"{count} {status}" for status, count in outcomes.most_common())
        parts.append(f"no field of {len(identifications)} tried ({min(fields):.3f}-{max(fields):.3f} deg) identified "
                     f"the stars: {ended}")
    return {"status": "not_solved", "reason": "; ".join(parts) or "no identification attempted"}


def format_text(record: dict) -> str:
    lines = [f"image: {record['image']} ({record['image_description']}), {record['spots']} spots",
             f"camera: {camera_summary_from(record['camera'])}"
             + (f", focal length +-{record['camera']['focal_sigma_px']:.2f} px (refined)"
                if record['camera'].get('focal_sigma_px') is not None else "")]
    if record["camera"].get("calibration"):
        lines.append(f"fitted camera: {calibration_summary(record['camera']['calibration'])}")
    if record.get("psf"):
        lines.append(f"psf: {psf_summary(record['psf'])}")
    if not record["solved"]:
        lines.append(f"NOT SOLVED: {record['reason']}")
        return "\n".join(lines)
    s = record["sigma_arcsec"]
    q = record["quaternion_xyzw"]
    lines += [
        f"solved: {record['reason']} ({record['algorithm']})",
        f"RA {record['ra_deg']:.5f} deg  Dec {record['dec_deg']:+.5f} deg  roll {record['roll_deg']:+.4f} deg",
        f"quaternion (x, y, z, w) sensor->ICRS: {q[0]:+.8f} {q[1]:+.8f} {q[2]:+.8f} {q[3]:+.8f}",
        f"1-sigma: cross-boresight {s['cross_boresight']:.2f}\" (x {s['x']:.2f}\", y {s['y']:.2f}\"), roll "
        f"{s['roll']:.2f}\"",
        f"residual RMS {record['residual_rms_arcsec']:.2f}\" over {len(record['matched'])} stars",
        "",
        f"{'HIP':>7} {'Hp':>6} {'x [px]':>9} {'y [px]':>9} {'residual':>9}",
    ]
    for m in record["matched"]:
        lines.append(f"{m['hip']:7d} {m['magnitude']:6.2f} {m['x']:9.2f} {m['y']:9.2f} {m['residual_arcsec']:8.2f}\"")
    return "\n".join(lines)


def calibration_summary(calibration: dict) -> str:
    """
    One line of a CameraCalibration.as_dict().

    Each fitted parameter +-1 sigma, what the stars left unfitted, the residual RMS.
    """
    units = {"f": " px", "cx": " px", "cy": " px", "k1": "", "k2": ""}
    fitted = ", ".join(f"{name} {calibration['value'][name]:.6g} +-{calibration['sigma'][name]:.2g}{units[name]}"
                       for name in calibration["fitted"])
    kept = f"; not constrained, kept: {', '.join(calibration['not_fitted'])}" if calibration["not_fitted"] else ""
    return (f"{fitted}{kept}; residual RMS {calibration['residual_rms_px']:.3f} px over {calibration['stars']} "
            "stars")


FIT_MODEL_TEXT = {"elliptical": ", stars fitted with its elliptical shape",
                  "core_halo": ", stars fitted with a core and halo (wings)",
                  "template": ", stars fitted with the image's own profile"}


def psf_summary(psf: dict) -> str:
    """One line on the PSF the centroider used (solution_record's "psf")."""
    if psf["source"] == "estimated":
        text = (f"sigma {psf['sigma_px']:.2f} +-{psf['sigma_uncertainty_px']:.2f} px estimated from {psf['stars']} "
                f"stars (major {psf['sigma_major_px']:.2f}, minor {psf['sigma_minor_px']:.2f} px at "
                f"{psf['angle_deg']:+.0f} deg)")
        text += ", ring stars (a defocused PSF)" if psf.get("annular") else ""
        text += FIT_MODEL_TEXT.get(psf.get("fit_model", ""), "")
        return text + (f", measured with the prior {psf['applied_sigma_px']:.2f} px"
                       if psf["applied_sigma_px"] != psf["sigma_px"] else "")
    if psf["source"] == "prior":
        return f"sigma {psf['sigma_px']:.2f} px (the prior: {psf['reason']})"
    return f"sigma {psf['sigma_px']:.2f} px (fixed)" if psf["sigma_px"] > 0 else "none (centre of gravity)"


def camera_summary_from(camera: dict) -> str:
    from ..models.camera import CameraModel

    return camera_summary(CameraModel(camera["width"], camera["height"], camera["fx"], camera["fy"], camera["cx"],
                                      camera["cy"], tuple(camera["distortion"])))


def centroid_config(pixels: np.ndarray, description: str, args: argparse.Namespace):
    """
    Return the CentroidConfig of an image file read by commands/images.py.

    `description` names its bit depth; under the --detection-sigma, --psf-sigma (None:
    estimated) and --max-spots options; solve and calibrate centroid alike.
    """
    from ..centroid import CentroidConfig

    saturation = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(pixels.dtype, 0.0)
    if "8-bit" in description and pixels.dtype.kind == "f":
        saturation = 255.0  # colour 8-bit averaged to float grey
    return CentroidConfig(detection_sigma=args.detection_sigma,
                          psf_sigma_px=1.0 if args.psf_sigma is None else args.psf_sigma,
                          psf_mode="auto" if args.psf_sigma is None else "fixed",
                          method="cog" if args.psf_sigma == 0 else "auto", max_spots=args.max_spots,
                          saturation_adu=saturation)


# A frame whose solve explains fewer than this share of its spots, while its elongated spots point
# every way (centroid/detection/texture.py), is centroided again with those ranked last.
TEXTURE_RETRY_MATCHED_SHARE = 1.0 / 3.0


def _matched(result: SolveResult) -> int:
    return int(result.identification.spot_index.size) if result.solved else 0


def texture_crowds_stars(spots, result: SolveResult) -> bool:
    """Whether texture (elongated spots pointing every way) may have crowded the stars out of `spots`."""
    from ..centroid.detection.texture import texture_streaks

    return bool(texture_streaks(spots.flags, spots.streak_angle).any()) and \
        _matched(result) < TEXTURE_RETRY_MATCHED_SHARE * len(spots)


@guarded(NAME)
def run(args: argparse.Namespace) -> int:
    from ..centroid import extract_spots
    from ..centroid.frame_check import frame_problem
    from ..identify.verify import MIN_STARS
    from .images import read_image

    started = time.perf_counter()
    image = read_image(args.image)
    read_s = time.perf_counter() - started
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
    config = centroid_config(pixels, image.description, args)
    saturation = config.saturation_adu
    centroid_started = time.perf_counter()
    spots = extract_spots(pixels, config)
    centroid_s = time.perf_counter() - centroid_started
    report = None if args.quiet else (lambda text: print(f"solve: {text}", file=sys.stderr, flush=True))
    options = SolveOptions(algorithm=args.algorithm, fov_tolerance_pct=args.fov_tolerance,
                           fov_step_pct=args.fov_step, field_search=args.field_search,
                           step_search_time_s=args.step_search_time, refine_focal=not args.no_refine,
                           centroid_sigma_floor_px=args.centroid_sigma_floor, max_time_s=args.max_time,
                           magnitude_limit=args.magnitude_limit, epoch_jyear=args.epoch)
    solve_started = time.perf_counter()
    result = solve_spots(spots, width, height, fov_deg=args.fov, camera=camera, options=options, report=report)
    solve_s = time.perf_counter() - solve_started
    texture_last = False
    if texture_crowds_stars(spots, result):
        # centroid/detection/texture.py: spots pointing every way fill the list and most are no star; the
        # point-like ones ranked first may be the stars (or the bloated stars were the streaks:
        # the solution matching more stars is kept).
        if report:
            report(f"{_matched(result)} of {len(spots)} spots matched, elongated spots point every way: "
                   "centroiding again with them ranked last")
        started_again = time.perf_counter()
        # The same pixels: the PSF estimated for them is the prior (no second estimate from a
        # measurement at the configured width).
        estimated = spots.psf is not None and spots.psf.estimated
        prior = spots.psf.applied_sigma_px if estimated else None
        texture_spots = extract_spots(pixels, replace(config, texture_last=True), psf_prior=prior,
                                      prior_rings=estimated and spots.psf.annular)
        solve_again = time.perf_counter()
        second = solve_spots(texture_spots, width, height, fov_deg=args.fov, camera=camera, options=options,
                             report=report)
        centroid_s += solve_again - started_again
        solve_s += time.perf_counter() - solve_again
        if _matched(second) > _matched(result):
            spots, result, texture_last = texture_spots, second, True
    record = solution_record(result, spots, str(args.image), image.description)
    record["texture_last"] = texture_last
    # Wall time of each stage [s]: reading and decoding the file, centroiding, field search + identification
    # + camera refinement; total to here (the record's own assembly included).
    record["timing_s"] = {"read": read_s, "centroid": centroid_s, "solve": solve_s,
                          "total": time.perf_counter() - started}
    problem = frame_problem(pixels, spots, MIN_STARS, saturation) if not result.solved else None
    if problem:
        record["reason"] = problem
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
