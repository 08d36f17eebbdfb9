# SPDX-License-Identifier: Apache-2.0
"""
CentroidConfig.texture_last: elongated spots that point every way (texture, not smear) are ranked after the stars.

A cloud lit from below (gran_IMG_007985) gives hundreds of elongated blobs brighter than the
faint stars; ranked by flux they fill max_spots and the fit budget (3 x max_spots) and the
stars never reach the identifier. A real smear or trail shares one direction, and is ranked
as before; without texture_last (the default) everything is ranked by flux. Frames from
bench/alt_renderer.py (not our simulator).
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import alt_renderer as alt  # noqa: E402

from star_tracker.centroid import CentroidConfig, extract_spots  # noqa: E402

DETECTOR = alt.Detector(sky_e=40.0, read_noise_e=5.0, gain_e_per_adu=1.0)
SIZE = 512
BLOB_DIRECTIONS = 50


def _frame(seed: int, blob_angles: np.ndarray):
    """
    10 bright and 30 faint (1,500 e-, SNR ~25) stars of PSF sigma 0.7 px, and 100 blobs of 6,000 e-.

    The blobs: elliptical Gaussians 2.5 x 0.8 px, two at each of `blob_angles` [rad]. Returns
    (image, faint stars' x, y [px]).
    """
    rng = np.random.default_rng([11, seed])
    x, y = alt.place_stars(SIZE, SIZE, 140, 14.0, 10.0, rng)
    star = alt.GaussianPsf(0.7)
    expected = (alt.star_signal(alt.StarField.build(star, x[:10], y[:10]), 30000.0, SIZE, SIZE)
                + alt.star_signal(alt.StarField.build(star, x[10:40], y[10:40]), 1500.0, SIZE, SIZE) + DETECTOR.sky_e)
    blob_x, blob_y = x[40:], y[40:]
    for k, angle in enumerate(blob_angles):
        blobs = alt.StarField.build(alt.EllipticalGaussianPsf(2.5, 0.8, angle), blob_x[k::blob_angles.size],
                                    blob_y[k::blob_angles.size])
        expected += alt.star_signal(blobs, 6000.0, SIZE, SIZE)
    electrons = rng.poisson(expected) + rng.normal(0.0, DETECTOR.read_noise_e, expected.shape)
    return np.clip(np.rint(electrons + 100.0), 0, 65535).astype(np.uint16), x[10:40], y[10:40]


def _faint_found(blob_angles_for, texture_last: bool = True) -> tuple[int, int]:
    found = total = 0
    for seed in range(3):
        image, x, y = _frame(seed, blob_angles_for(seed))
        # room for all 40 stars
        spots = extract_spots(image, replace(CentroidConfig(), max_spots=40, texture_last=texture_last))
        distance = np.hypot(x[:, None] - spots.x[None], y[:, None] - spots.y[None])
        found += int((distance.min(axis=1) < 1.5).sum())
        total += x.size
    return found, total


def _every_way(seed: int) -> np.ndarray:
    return (np.arange(BLOB_DIRECTIONS) + 0.5 * seed) * np.pi / BLOB_DIRECTIONS


def test_faint_stars_are_kept_before_texture_pointing_every_way():
    found, total = _faint_found(_every_way)
    assert found >= 0.95 * total, f"{found} of {total} faint stars kept"


def test_by_default_the_texture_keeps_its_rank_by_flux():
    # The blobs, 4x brighter than the faint stars, take the 40 places (bloated stars of poor
    # optics point every way too: `solve` chooses texture_last only where it explains more).
    found, total = _faint_found(_every_way, texture_last=False)
    assert found <= 0.1 * total, f"{found} of {total}"


def test_elongated_spots_sharing_one_direction_keep_their_rank():
    # The same blobs all along one direction (as a smear): ranked by flux as before, they keep
    # their places (the rule must not demote a trailed frame's stars).
    found, total = _faint_found(lambda seed: np.full(BLOB_DIRECTIONS, 0.3 + seed))
    assert found <= 0.1 * total, f"{found} of {total}: aligned elongated spots were demoted"
