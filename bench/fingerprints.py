# SPDX-License-Identifier: Apache-2.0
"""
Behaviour fingerprints.

Hashes of what the pipeline computes on fixed seeds, so a change that should not alter behaviour (a
refactor) can be checked bit for bit.

    python -m bench.fingerprints --write bench/fingerprints.json   # record
    python -m bench.fingerprints --check bench/fingerprints.json   # compare (exit 1 on a difference)

What is hashed (SHA-256 of the raw array bytes):
- rendered frames: the default camera and sensor at rest, under a body rate, and with false
  objects, each on two frame seeds;
- the spots extracted from each of those frames (default config; the rated frames also
  rate-aided with the true rate);
- identification by every algorithm of fixed scenes of every setup in SETUPS (status, HIP
  ids, spot indices, quaternion, covariance), with a time budget large enough that host
  speed cannot change a result;
- a tracked sequence of rendered frames (mode, HIP ids, quaternion, rate);
- every frame's PSF as the centroider saw it (`Spots.psf`, every field) and the model its
  single stars were fitted with (`Spots.fit_model`), beside its spots;
- frames of the second renderer (bench/alt_renderer.py): defocused rings, an astigmatic and a
  Moffat PSF, stars among cosmic-ray tracks and hot pixels, wide stars at the 1 px prior (the
  wider-prior search), each measured cold and again with its own estimate as a running prior
  (the centroider node's path);
- the spots, PSF and solution (`star-tracker solve` at its defaults) of a few real images of
  ../shared/realdata (left out, and said so, where the corpus is absent).
Hashes are of float bytes, so they are only comparable on one machine and library set.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys

from pathlib import Path

import numpy as np

from star_tracker.centroid import extract_spots
from star_tracker.centroid.smear import SmearModel
from star_tracker.identify import ALGORITHMS, DatabaseConfig, IdentifyConfig, load_or_build_database, make_identifier
from star_tracker.track.tracking import Tracker
from star_tracker.models.attitude import radec_roll_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.models.catalog import load_hipparcos
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import FalseObjectModel, StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel
from star_tracker.sim.scenes import SETUPS, make_scene

from . import alt_renderer as alt

SCENES_PER_SETUP = {"toloei_4_136": 2, "toloei_6_50": 4}
DEFAULT_SCENES = 8
EXPOSURE_S = 0.1


def digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a))
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def spots_digest(spots) -> str:
    return digest(*(getattr(spots, f) for f in spots.__dataclass_fields__
                    if isinstance(getattr(spots, f), np.ndarray)))


def psf_digest(spots) -> str:
    """Return the frame's PSF record (every field, in order) and its single stars' fit model."""
    psf = spots.psf
    values = [] if psf is None else [repr(getattr(psf, f)) for f in psf.__dataclass_fields__]
    return digest(np.frombuffer("|".join(values + [spots.fit_model]).encode(), np.uint8))


def measured(out: dict, key: str, spots) -> None:
    out[f"spots/{key}"] = spots_digest(spots)
    out[f"psf/{key}"] = psf_digest(spots)


def frames(catalog) -> dict[str, str]:
    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0))
    start = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.0)
    cases = {
        "rest": (np.zeros(3), FalseObjectModel()),
        "rate": (np.radians([0.3, 0.4, 0.05]), FalseObjectModel()),
        "fast": (np.radians([1.2, -0.9, 0.2]), FalseObjectModel()),
    }
    out = {}
    for name, (rate, false_objects) in cases.items():
        renderer = StarFieldRenderer(camera, SensorModel(exposure_s=EXPOSURE_S), catalog, magnitude_limit=7.5,
                                     false_objects=false_objects)
        motion = ConstantRateMotion(start, body_rate=rate)
        for index in range(2):
            frame = renderer.render(motion, stamp_s=1.0 + index, seed=frame_seed(7, index))
            key = f"{name}/{index}"
            out[f"frame/{key}"] = digest(frame.image)
            measured(out, key, extract_spots(frame.image))
            if np.any(rate):
                smear = SmearModel(camera, frame.truth.body_rate, EXPOSURE_S)
                measured(out, f"aided/{key}", extract_spots(frame.image, smear=smear))
    cosmic = StarFieldRenderer(camera, SensorModel(exposure_s=EXPOSURE_S, cosmic_ray_rate_per_cm2_s=2000.0),
                               catalog, magnitude_limit=7.5)
    frame = cosmic.render(ConstantRateMotion(start, body_rate=np.zeros(3)), stamp_s=1.0, seed=frame_seed(7, 5))
    out["frame/cosmic_rays"] = digest(frame.image)
    measured(out, "cosmic_rays", extract_spots(frame.image))
    return out


# Second-renderer frames (bench/alt_renderer.py): name -> (PSF, detector, flux per star [e-], stars).
ALT_SIZE = 384
ALT_DETECTOR = alt.Detector(sky_e=40.0, read_noise_e=5.0, hot_pixel_fraction=1e-4, cosmic_rays_per_frame=3.0)
ALT_FRAMES = {
    "rings": (alt.AnnulusPsf.with_equivalent_sigma(2.0), ALT_DETECTOR, 30000.0, 40),
    "rings_faint": (alt.AnnulusPsf.with_equivalent_sigma(3.0), ALT_DETECTOR, 5000.0, 40),
    # too few usable stars at the 1 px prior: the wider-prior search
    "rings_wider": (alt.AnnulusPsf.with_equivalent_sigma(3.0), ALT_DETECTOR, 2000.0, 60),
    "astigmatic": (alt.EllipticalGaussianPsf(1.3, 1.0 / 1.3, np.radians(30.0)), ALT_DETECTOR, 5000.0, 40),
    "moffat": (alt.MoffatPsf(1.0 / alt.SIGMA_PER_FWHM, beta=3.0), ALT_DETECTOR, 5000.0, 40),
    "moffat_template": (alt.MoffatPsf(1.0 / alt.SIGMA_PER_FWHM, beta=2.5), ALT_DETECTOR, 30000.0, 40),
    "moffat_core_halo": (alt.MoffatPsf(1.5 / alt.SIGMA_PER_FWHM, beta=3.0), ALT_DETECTOR, 60000.0, 40),
    "tracks": (alt.GaussianPsf(1.0),
               alt.Detector(sky_e=40.0, read_noise_e=5.0, hot_pixel_fraction=1e-3, cosmic_rays_per_frame=60.0),
               5000.0, 40),
    "wide": (alt.GaussianPsf(3.0), ALT_DETECTOR, 30000.0, 40),
    "narrow": (alt.GaussianPsf(0.5), ALT_DETECTOR, 1000.0, 40),
}


def alt_frames() -> dict[str, str]:
    """Each frame measured cold, then with its own estimate as the running prior (the node's next frame)."""
    out = {}
    for index, (name, (psf, detector, flux, stars)) in enumerate(ALT_FRAMES.items()):
        rng = np.random.default_rng([23, index])
        sigma = psf.equivalent_sigma_px
        x, y = alt.place_stars(ALT_SIZE, ALT_SIZE, stars, 12.0, 3 * sigma + 8, rng)
        frame = alt.render(alt.StarField.build(psf, x, y), flux, detector, ALT_SIZE, ALT_SIZE, rng)
        out[f"frame/alt/{name}"] = digest(frame.image)
        cold = extract_spots(frame.image)
        measured(out, f"alt/{name}", cold)
        if cold.psf is not None and cold.psf.estimated:
            again = extract_spots(frame.image, psf_prior=cold.psf.applied_sigma_px, prior_rings=cold.psf.annular)
            measured(out, f"alt/{name}/prior", again)
    return out


# Real images (../shared/realdata): round stars, a webcam, a wide-field lens, a crowded long
# exposure, a texture frame, a defocused camera.
REAL_IMAGES = ("openstartracker_img5", "ubst_webcam_w1", "lost_img_7660", "gran_polar_30sec",
               "gran_sagitario_2seg_gain_max", "unh_DSC_0058")
CORPUS = Path(__file__).resolve().parents[1].parent / "shared" / "realdata"


def real_images() -> dict[str, str]:
    """Spots, PSF and solve (`star-tracker solve IMG --fov F` at defaults) of REAL_IMAGES; {} without the corpus."""
    from star_tracker.cli import build_parser
    from star_tracker.commands.images import read_image
    from star_tracker.commands.solve import SolveOptions, centroid_config, solve_spots

    manifest = CORPUS / "MANIFEST.json"
    if not manifest.is_file():
        return {}
    entries = {e["id"]: e for e in json.loads(manifest.read_text())["images"]}
    out = {}
    for image_id in REAL_IMAGES:
        entry = entries[image_id]
        image = read_image(CORPUS / entry["file"])
        args = build_parser().parse_args(["solve", str(CORPUS / entry["file"]), "--fov", f"{entry['fov_h_deg']:g}"])
        spots = extract_spots(image.pixels, centroid_config(image.pixels, image.description, args))
        measured(out, f"real/{image_id}", spots)
        height, width = image.pixels.shape
        # Time budgets large enough that host speed cannot change a result.
        result = solve_spots(spots, width, height, fov_deg=args.fov,
                             options=SolveOptions(max_time_s=15.0, step_search_time_s=60.0))
        out[f"solve/{image_id}"] = identification_digest(result.identification) if result.solved else "unsolved"
    return out


def identification_digest(result) -> str:
    attitude = result.attitude
    return digest(np.frombuffer(result.status.encode(), np.uint8), result.hip, result.spot_index,
                  attitude.quaternion if attitude is not None else np.zeros(0),
                  attitude.covariance if attitude is not None else np.zeros(0))


def identification(catalog, database) -> dict[str, str]:
    out = {}
    for setup_name, setup in SETUPS.items():
        rng = np.random.default_rng([11, len(setup_name)])
        scenes = [make_scene(setup, catalog, rng) for _ in range(SCENES_PER_SETUP.get(setup_name, DEFAULT_SCENES))]
        for algorithm in ALGORITHMS:
            identifier = make_identifier(algorithm, database, IdentifyConfig(max_time_s=60.0))
            for index, scene in enumerate(scenes):
                result = identifier.identify(scene.spots, setup.camera)
                out[f"identify/{setup_name}/{algorithm}/{index}"] = identification_digest(result)
    return out


def tracking(catalog, database) -> dict[str, str]:
    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0))
    renderer = StarFieldRenderer(camera, SensorModel(exposure_s=EXPOSURE_S), catalog, magnitude_limit=7.5)
    motion = ConstantRateMotion(radec_roll_to_matrix(np.radians(200.0), np.radians(-30.0), 0.4),
                                body_rate=np.radians([0.5, -0.3, 0.1]))
    tracker = Tracker(make_identifier("hybrid", database, IdentifyConfig(max_time_s=60.0)))
    out = {}
    for index in range(8):
        stamp_s = 1.0 + 0.1 * index
        frame = renderer.render(motion, stamp_s=stamp_s, seed=frame_seed(3, index))
        tracked = tracker.process(int(round(stamp_s * 1e9)), extract_spots(frame.image), camera)
        rate = tracked.rate.angular_velocity if tracked.rate is not None else np.zeros(0)
        out[f"track/{index}"] = digest(np.frombuffer(tracked.mode.encode(), np.uint8),
                                       identification_digest(tracked.identification).encode(), rate)
    return out


def compute() -> dict[str, str]:
    database = load_or_build_database(DatabaseConfig())
    catalog = load_hipparcos().at_epoch(database.config.epoch_jyear)
    out = {}
    out.update(frames(catalog))
    out.update(identification(catalog, database))
    out.update(tracking(catalog, database))
    out.update(alt_frames())
    out.update(real_images())
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--write", metavar="JSON")
    group.add_argument("--check", metavar="JSON")
    args = parser.parse_args(argv)
    current = compute()
    if args.write:
        with open(args.write, "w") as f:
            json.dump(current, f, indent=1, sort_keys=True)
            f.write("\n")
        print(f"{len(current)} fingerprints written to {args.write}")
        return 0
    with open(args.check) as f:
        reference = json.load(f)
    keys = reference.keys() | current.keys()
    if not any(k.startswith("solve/") for k in current):
        print(f"real-image corpus absent ({CORPUS}): its fingerprints are not compared")
        keys = {k for k in keys if not k.startswith(("real/", "solve/")) and "/real/" not in k}
    differ = sorted(k for k in keys if reference.get(k) != current.get(k))
    for key in differ:
        print(f"DIFFERS {key}: {reference.get(key)} -> {current.get(key)}")
    print(f"{len(keys) - len(differ)} of {len(keys)} fingerprints identical")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
