# SPDX-License-Identifier: Apache-2.0
"""
calibrate_camera over many frames: its time and result (`calibrate` of a long bag, the online fit).

Synthetic frames, no rendering: 60 points uniform over a 1024x768 image per frame, their rays
through a known camera (20 deg, f +0.3 %, principal point (+5, -4) px off centre, k1 0.1), at
random attitudes; 0.2 px Gaussian noise on the positions, starting attitudes 1e-4 rad off.

    python -m bench.calibration_scale 600 2000

prints, per frame count, the wall time of calibrate_camera [s], the peak memory the process
reached [MB] and each fitted value with its 1-sigma beside the truth. For an A/B against
another commit, run it with PYTHONPATH at a worktree of that commit.
"""
from __future__ import annotations

import math
import resource
import sys
import time

import numpy as np


def main(argv: list[str]) -> None:
    from star_tracker.models.attitude import rotation_vector_to_matrix
    from star_tracker.models.camera import CameraModel
    from star_tracker.models.camera_calibration import CalibrationFrame, calibrate_camera

    width, height = 1024, 768
    nominal = CameraModel.from_fov(width, height, math.radians(20.0))
    true = CameraModel(width, height, nominal.fx * 1.003, nominal.fy * 1.003, nominal.cx + 5.0, nominal.cy - 4.0,
                       (0.1, 0.0, 0.0, 0.0, 0.0))
    truth = {"f": true.fx, "k1": 0.1, "k2": 0.0, "cx": true.cx, "cy": true.cy}
    for count in [int(a) for a in argv] or [600]:
        rng = np.random.default_rng(1)
        frames = []
        for _ in range(count):
            rotation = rotation_vector_to_matrix(rng.normal(size=3))
            u, v = rng.uniform(0, width, 60), rng.uniform(0, height, 60)
            stars = true.pixel_to_ray(u, v) @ rotation.T
            frames.append(CalibrationFrame(u + rng.normal(0, 0.2, 60), v + rng.normal(0, 0.2, 60),
                                           np.tile(0.04 * np.eye(2), (60, 1, 1)), stars,
                                           rotation @ rotation_vector_to_matrix(rng.normal(0, 1e-4, 3))))
        started = time.perf_counter()
        result = calibrate_camera(frames, nominal)
        elapsed = time.perf_counter() - started
        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        fitted = ", ".join(f"{n} {result.value[n]:.4f} ± {result.sigma[n]:.4f} (truth {truth[n]:.4f})"
                           for n in result.fitted)
        print(f"{count} frames: {elapsed:.2f} s, peak {peak_mb:.0f} MB; {fitted}")


if __name__ == "__main__":
    main(sys.argv[1:])
