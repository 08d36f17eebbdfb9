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
- a tracked sequence of rendered frames (mode, HIP ids, quaternion, rate).
Hashes are of float bytes, so they are only comparable on one machine and library set.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys

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
            out[f"spots/{key}"] = spots_digest(extract_spots(frame.image))
            if np.any(rate):
                smear = SmearModel(camera, frame.truth.body_rate, EXPOSURE_S)
                out[f"spots_aided/{key}"] = spots_digest(extract_spots(frame.image, smear=smear))
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
    differ = sorted(k for k in reference.keys() | current.keys() if reference.get(k) != current.get(k))
    for key in differ:
        print(f"DIFFERS {key}: {reference.get(key)} -> {current.get(key)}")
    print(f"{len(reference) - len(differ)} of {len(reference)} fingerprints identical")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
