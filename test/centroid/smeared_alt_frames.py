# SPDX-License-Identifier: Apache-2.0
"""
Smeared star fields from the independent renderer (bench/alt_renderer.py), which has no motion.

A star moving uniformly by a smear vector during the exposure is the mean of its PSF at
sub-steps along that vector (SUB_STEPS_PER_PX per pixel of smear); the stars, a sky with an
optional linear ramp (stray light) and the detector's noise are added as alt_renderer.render
does. Used by the PSF loop's tests on frames our simulator did not make.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from bench import alt_renderer as alt
from star_tracker.centroid.streak.smear import SmearModel
from star_tracker.models.camera import CameraModel

SIZE = 512  # [px]
EXPOSURE_S = 0.1
SUB_STEPS_PER_PX = 4
CAMERA = CameraModel.from_fov(SIZE, SIZE, math.radians(8.0))


class SmearedFrame(NamedTuple):
    image: np.ndarray  # uint16 [ADU]
    x: np.ndarray  # the stars' mid-exposure positions [px]
    y: np.ndarray
    smear: SmearModel  # the body rate that smears them so (for a rate-aided frame)


def smeared_frame(psf, smear_px: float, angle_rad: float, seed: int, flux_e: float = 20000.0, stars: int = 40,
                  ramp_e_per_px: float = 0.0, sky_e: float = 40.0) -> SmearedFrame:
    """
    Return a frame of `stars` stars of `psf` smeared by smear_px [px] along angle_rad [rad from +x toward +y].

    flux_e [e-]: the median star (spread log-uniformly over e^-1..e^1 of it); ramp_e_per_px:
    a sky gradient [e-/px per px] down and to the right; sky_e [e-/px] the sky level.
    """
    rng = np.random.default_rng(seed)
    x, y = alt.place_stars(SIZE, SIZE, stars, 40.0, 30.0, rng)
    flux = flux_e * np.exp(rng.uniform(-1.0, 1.0, x.size))
    vector = smear_px * np.array([math.cos(angle_rad), math.sin(angle_rad)])
    steps = max(1, int(round(smear_px * SUB_STEPS_PER_PX)))
    signal = np.zeros((SIZE, SIZE))
    for t in (np.arange(steps) + 0.5) / steps - 0.5:
        for k in range(x.size):
            stamp = alt.star_stamp(psf, x[k] + t * vector[0], y[k] + t * vector[1])
            _add_clipped(signal, stamp, flux[k] / steps)
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    detector = alt.Detector(sky_e=sky_e)
    expected = signal + detector.sky_e + ramp_e_per_px * (2.0 * SIZE - rows - cols)
    electrons = rng.poisson(expected) + rng.normal(0.0, detector.read_noise_e, expected.shape)
    image = np.clip(np.rint(electrons / detector.gain_e_per_adu + detector.bias_adu), 0, 65535).astype(np.uint16)
    # A rate about the camera's axes perpendicular to the smear moves the stars along it.
    rate = smear_px / (CAMERA.fx * EXPOSURE_S)
    omega = rate * np.array([math.sin(angle_rad), -math.cos(angle_rad), 0.0])
    return SmearedFrame(image, x, y, SmearModel(CAMERA, omega, EXPOSURE_S))


def _add_clipped(signal: np.ndarray, stamp, flux: float) -> None:
    """Add flux [e-] x the stamp's pixel fractions to `signal`, the part off the image lost."""
    h, w = stamp.fractions.shape
    r0, c0 = max(stamp.row0, 0), max(stamp.col0, 0)
    r1, c1 = min(stamp.row0 + h, signal.shape[0]), min(stamp.col0 + w, signal.shape[1])
    signal[r0:r1, c0:c1] += flux * stamp.fractions[r0 - stamp.row0:r1 - stamp.row0, c0 - stamp.col0:c1 - stamp.col0]


def found(spots, x: np.ndarray, y: np.ndarray, reach_px: float = 1.0) -> tuple[int, int]:
    """Return (stars with a spot within reach_px [px], spots with no star within it)."""
    d = np.hypot(spots.x[:, None] - x[None, :], spots.y[:, None] - y[None, :])
    if d.size == 0:
        return 0, len(spots)
    return int((d.min(axis=0) < reach_px).sum()), int((d.min(axis=1) >= reach_px).sum())
