# SPDX-License-Identifier: Apache-2.0
"""
Median extract_spots CPU time [ms] on 20 nominal frames (default camera and sensor, 0.2 deg/s), in-process.

For an A/B against another commit, run this file with PYTHONPATH at a worktree of it, in
alternation with the current tree (docs/BENCHMARKS.md § Centroiding time against the code
before issue 17):

    PYTHONPATH=../wt/pre17 python bench/centroid_time.py 10; PYTHONPATH=. python bench/centroid_time.py 10

The argument: passes over the 20 frames (default 5). Prints one number. It imports only what
the centroider had before issue 17, so that an older tree runs it too.
"""
from __future__ import annotations

import sys
import time

import numpy as np


def main(argv: list[str]) -> None:
    from star_tracker.centroid import CentroidConfig, extract_spots
    from star_tracker.models.attitude import radec_roll_to_matrix
    from star_tracker.models.camera import CameraModel
    from star_tracker.models.catalog import load_hipparcos
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import StarFieldRenderer, frame_seed
    from star_tracker.sim.sensor import SensorModel

    passes = int(argv[0]) if argv else 5
    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0))
    renderer = StarFieldRenderer(camera, SensorModel(), load_hipparcos().at_epoch(2026.0), magnitude_limit=7.5)
    rng = np.random.default_rng(2)
    frames = []
    for index in range(20):
        ra, dec, roll = rng.uniform(0, 2 * np.pi), np.arcsin(rng.uniform(-1, 1)), rng.uniform(0, 2 * np.pi)
        start = radec_roll_to_matrix(ra, dec, roll)
        motion = ConstantRateMotion(start, np.radians([0.2, 0.0, 0.0]))
        frames.append(renderer.render(motion, 0.0, frame_seed(1, index)).image)
    for frame in frames[:3]:  # compile / load the kernels
        extract_spots(frame, CentroidConfig())
    times = []
    for _ in range(passes):
        for frame in frames:
            started = time.process_time()
            extract_spots(frame, CentroidConfig())
            times.append(time.process_time() - started)
    print(f"{np.median(times) * 1000:.2f}")


if __name__ == "__main__":
    main(sys.argv[1:])
