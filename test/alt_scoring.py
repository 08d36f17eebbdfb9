# SPDX-License-Identifier: Apache-2.0
"""
The centroider's tests on bench/alt_renderer.py frames: spots at the defaults scored against truth and CRB.

Stars near a hot pixel or cosmic ray (within `clear_px` + half the defect's extent) are not
scored; a star is found when a spot lies within `match_px`.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/ is not an installed package
from bench import alt_renderer as alt  # noqa: E402

from star_tracker.centroid import CentroidConfig, extract_spots  # noqa: E402

SIZE = 512
DETECTOR = alt.Detector(sky_e=40.0, read_noise_e=5.0, gain_e_per_adu=1.0, hot_pixel_fraction=1e-4,
                        cosmic_rays_per_frame=3.0)


def rms_over_crb(psf, flux_e: float, seeds, clear_px: float, match_px: float = 2.0, check=None):
    """
    Return (RMS 2-D error / sqrt(mean CRB trace), stars found, stars scored) over frames of 50 stars >= 12 px apart.

    One frame per seed (numpy seed sequences); `check(spots)`, when given, runs on each
    frame's Spots (e.g. assertions on the PSF estimate).
    """
    errors, bound, found, scored = [], [], 0, 0
    for seed in seeds:
        rng = np.random.default_rng(seed)
        x, y = alt.place_stars(SIZE, SIZE, 50, 12.0, 12.0, rng)
        field = alt.StarField.build(psf, x, y)
        frame = alt.render(field, flux_e, DETECTOR, SIZE, SIZE, rng)
        spots = extract_spots(frame.image, CentroidConfig())
        if check is not None:
            check(spots)
        truth = frame.truth
        clear = np.ones(x.size, bool)
        if truth.defect_x.size:
            clear = ~(np.hypot(x[:, None] - truth.defect_x[None], y[:, None] - truth.defect_y[None])
                      < clear_px + 0.5 * truth.defect_extent_px[None]).any(axis=1)
        d = np.hypot(x[:, None] - spots.x[None], y[:, None] - spots.y[None])
        nearest = d.argmin(axis=1)
        hit = clear & (d[np.arange(x.size), nearest] < match_px)
        crb = alt.cramer_rao(field, flux_e, DETECTOR)
        errors.append(d[np.arange(x.size), nearest][hit] ** 2)
        bound.append((crb[:, 0, 0] + crb[:, 1, 1])[hit])
        found += int(hit.sum())
        scored += int(clear.sum())
    ratio = float(np.sqrt(np.mean(np.concatenate(errors)) / np.mean(np.concatenate(bound))))
    return ratio, found, scored
