# SPDX-License-Identifier: Apache-2.0
"""
A defocused camera's frames in the centroider node: the running prior with and without the ring shape.

    python -m bench.ring_prior_time [FRAMES]

Frames from bench/alt_renderer.py (not our renderer): defocused annulus PSFs (equivalent
sigma 1.5, 2 and 3 px), 60 stars of 5000 e- on 1024², FRAMES each (default 5). Each frame is
measured cold (no prior), then from the cold estimate's width alone (`psf_prior`, as the node
did before session 29: measured twice), then from its width and ring shape (`prior_rings`,
the node now: once). Prints per PSF the median CPU time [ms] of both, their ratio, and whether
the spots of the ring prior equal the cold measurement's.
"""
from __future__ import annotations

import statistics
import sys
import time

import numpy as np

from bench import alt_renderer as alt
from star_tracker.centroid import CentroidConfig, extract_spots

SIZE = 1024
STARS = 60
FLUX_E = 5000.0
DETECTOR = alt.Detector(sky_e=40.0, read_noise_e=5.0, gain_e_per_adu=1.0)


def cpu_ms(call, repeat: int = 5) -> float:
    runs = []
    for _ in range(repeat):
        started = time.process_time()
        call()
        runs.append(time.process_time() - started)
    return 1000.0 * statistics.median(runs)


def main(argv: list[str]) -> None:
    frames = int(argv[0]) if argv else 5
    config = CentroidConfig()
    for sigma in (1.5, 2.0, 3.0):
        psf = alt.AnnulusPsf.with_equivalent_sigma(sigma)
        width_only, with_rings, same = [], [], 0
        for k in range(frames):
            rng = np.random.default_rng([29, k])
            x, y = alt.place_stars(SIZE, SIZE, STARS, max(5.0 * sigma / alt.SIGMA_PER_FWHM, 12.0), 3 * sigma + 8, rng)
            image = alt.render(alt.StarField.build(psf, x, y), FLUX_E, DETECTOR, SIZE, SIZE, rng).image
            cold = extract_spots(image, config)
            prior = cold.psf.applied_sigma_px
            rings = bool(cold.psf.annular)
            warm = extract_spots(image, config, psf_prior=prior, prior_rings=rings)
            same += int(np.array_equal(warm.x, cold.x) and np.array_equal(warm.y, cold.y))
            width_only.append(cpu_ms(lambda: extract_spots(image, config, psf_prior=prior)))
            with_rings.append(cpu_ms(lambda: extract_spots(image, config, psf_prior=prior, prior_rings=rings)))
        a, b = statistics.median(width_only), statistics.median(with_rings)
        print(f"annulus sigma {sigma:.1f} px: width prior {a:.1f} ms, width + rings {b:.1f} ms ({b / a:.2f}x); "
              f"spots equal to the cold measurement's on {same} of {frames} frames")


if __name__ == "__main__":
    main(sys.argv[1:])
