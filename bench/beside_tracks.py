# SPDX-License-Identifier: Apache-2.0
"""
Stars sharing a detection footprint with a neighbour star or a cosmic-ray track, counted.

Frames from bench/alt_renderer.py (not our renderer: its own PSFs and noise), 512², each with
eight pairs of stars 7-16 px apart and eight stars with a 1 px wide track starting 4-5 px from
them (5000 e- per star, 15000 e- per track; the track's charge is added without shot noise).
test/centroid/test_stars_beside_tracks.py asserts on these counts; for more frames:

    python -m bench.beside_tracks 80

prints, per PSF (Gaussian sigma 1 px, defocused annulus), the paired and beside-track stars
missed (no spot within 1 px), the RMS error of those found [px] and the spots on tracks.
"""
from __future__ import annotations

import sys
from typing import NamedTuple

import numpy as np

from bench import alt_renderer as alt

SIZE = 512
DETECTOR = alt.Detector(sky_e=40.0, read_noise_e=5.0, gain_e_per_adu=1.0)
TRACK_E = 15000.0  # a cosmic ray's charge [e-] along its TRACK_PX pixels
TRACK_PX = 10
PSFS = {"annulus": alt.AnnulusPsf(1.71, 0.85, 0.30), "gaussian": alt.GaussianPsf(1.0)}


def scene(psf, seed: int):
    """
    Eight pairs of stars 7-16 px apart and eight stars with a track starting 4-5 px from them, 5000 e- each.

    Returns (image [ADU], star x, y, track pixel x, y, whether each star has a track beside it).
    """
    rng = np.random.default_rng(seed)
    cells = [(64 + 128 * (k % 4), 64 + 128 * (k // 4)) for k in range(16)]
    x, y, beside, track_x, track_y = [], [], [], [], []
    for k, (cx, cy) in enumerate(cells):
        x0, y0 = cx + rng.uniform(-5, 5), cy + rng.uniform(-5, 5)
        angle = rng.uniform(0, np.pi)
        direction = np.array([np.cos(angle), np.sin(angle)])
        if k < 8:  # a pair of stars
            separation = rng.uniform(7.0, 16.0)
            x += [x0, x0 + separation * direction[0]]
            y += [y0, y0 + separation * direction[1]]
            beside += [False, False]
        else:  # a star and a straight track along `direction`, 1 px wide
            x.append(x0)
            y.append(y0)
            beside.append(True)
            start = rng.uniform(4.0, 5.0)
            steps = start + np.arange(TRACK_PX)
            track_x.append(np.rint(x0 + steps * direction[0]).astype(int))
            track_y.append(np.rint(y0 + steps * direction[1]).astype(int))
    frame = alt.render(alt.StarField.build(psf, np.array(x), np.array(y)), 5000.0, DETECTOR, SIZE, SIZE, rng)
    image = frame.image.astype(np.float64)
    for tx, ty in zip(track_x, track_y):
        image[ty, tx] += TRACK_E / TRACK_PX / DETECTOR.gain_e_per_adu
    image = np.clip(image, 0, 65535).astype(np.uint16)
    return image, np.array(x), np.array(y), np.concatenate(track_x), np.concatenate(track_y), np.array(beside)


class Counts(NamedTuple):
    """Over the frames: stars missed (paired, beside a track), errors [px] of those found, spots on tracks."""

    missed_paired: int
    missed_beside: int
    errors: list
    on_tracks: int

    @property
    def rms_px(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.errors))))


def count(psf, seeds) -> Counts:
    """Extract every frame of `seeds` at the centroider's defaults and count against the truth."""
    from star_tracker.centroid import CentroidConfig, extract_spots

    missed_paired, missed_beside, errors, on_tracks = 0, 0, [], 0
    for seed in seeds:
        image, x, y, track_x, track_y, beside = scene(psf, seed)
        spots = extract_spots(image, CentroidConfig())
        distance = np.hypot(spots.x[:, None] - x[None], spots.y[:, None] - y[None])
        nearest = distance.min(axis=0)
        missed_paired += int(np.sum(nearest[~beside] > 1.0))
        missed_beside += int(np.sum(nearest[beside] > 1.0))
        errors += nearest[nearest <= 1.0].tolist()
        unmatched = distance.min(axis=1) > 2.0
        to_track = np.hypot(spots.x[:, None] - track_x[None], spots.y[:, None] - track_y[None]).min(axis=1)
        on_tracks += int(np.sum(unmatched & (to_track < 2.0)))
    return Counts(missed_paired, missed_beside, errors, on_tracks)


def main(argv: list[str]) -> None:
    frames = int(argv[0]) if argv else 40
    print(f"{frames} frames: {16 * frames} paired stars and {8 * frames} beside a track per PSF")
    for name, psf in PSFS.items():
        counts = count(psf, range(frames))
        print(f"{name}: missed paired {counts.missed_paired}, missed beside a track {counts.missed_beside}, "
              f"RMS {counts.rms_px:.4f} px, spots on tracks {counts.on_tracks}")


if __name__ == "__main__":
    main(sys.argv[1:])
