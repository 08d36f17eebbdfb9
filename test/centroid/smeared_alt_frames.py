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


class JitteredFrame(NamedTuple):
    image: np.ndarray  # uint16 [ADU]
    x: np.ndarray  # the stars' exposure-average positions [px]
    y: np.ndarray
    gyro_offsets_s: np.ndarray  # (n,) the gyro's sample times [s from mid-exposure]
    gyro_rates: np.ndarray  # (n, 3) its noise-free samples [rad/s, sensor frame]
    mid_exposure_offset_rad: np.ndarray  # (3,) phi(0) less phi's exposure mean: R_mid = R_mean exp([phi x])


def jittered_frame(psf, drift_rad_s: np.ndarray, jitter_rad: np.ndarray, jitter_hz: float, phase_rad: float,
                   seed: int, flux_e: float = 40000.0, stars: int = 40, steps: int = 200, gyro_hz: float = 100.0
                   ) -> JitteredFrame:
    """
    Return a frame whose stars move by a drift plus a sinusoidal jitter about the cross-boresight axes.

    The body turns by phi(t) = drift t + jitter sin(2 pi f t + phase) (drift_rad_s, jitter_rad: (2,)
    about the camera's x and y axes); near the optical axis a turn phi moves a star by
    (-fx phi_y, fy phi_x) [px] (the sign convention of smeared_frame's rate). Each star is the
    mean of its PSF at `steps` instants evenly spread over the exposure, placed so that its
    exposure-average position is (x, y). The gyro: the rate d phi / dt at gyro_hz over the
    exposure and the 0.15 s before it (as a gyro's last samples), noise free.
    """
    rng = np.random.default_rng(seed)
    x, y = alt.place_stars(SIZE, SIZE, stars, 40.0, 30.0, rng)
    flux = flux_e * np.exp(rng.uniform(-1.0, 1.0, x.size))
    drift, jitter = np.asarray(drift_rad_s, float), np.asarray(jitter_rad, float)
    omega_j = 2.0 * math.pi * jitter_hz

    def turn(t):
        return np.multiply.outer(t, drift) + np.multiply.outer(np.sin(omega_j * t + phase_rad), jitter)

    times = ((np.arange(steps) + 0.5) / steps - 0.5) * EXPOSURE_S
    phi = turn(times)
    mid = turn(np.zeros(1))[0] - phi.mean(axis=0)
    phi = phi - phi.mean(axis=0)
    dx, dy = -CAMERA.fx * phi[:, 1], CAMERA.fy * phi[:, 0]
    signal = np.zeros((SIZE, SIZE))
    for k in range(x.size):
        for step in range(steps):
            _add_clipped(signal, alt.star_stamp(psf, x[k] + dx[step], y[k] + dy[step]), flux[k] / steps)
    detector = alt.Detector()
    electrons = rng.poisson(signal + detector.sky_e) + rng.normal(0.0, detector.read_noise_e, signal.shape)
    image = np.clip(np.rint(electrons / detector.gain_e_per_adu + detector.bias_adu), 0, 65535).astype(np.uint16)
    offsets = 0.5 * EXPOSURE_S - (np.arange(int(round(0.25 * gyro_hz))) + 0.5) / gyro_hz
    swing = omega_j * np.cos(omega_j * offsets + phase_rad)
    rate = np.multiply.outer(np.ones_like(offsets), drift) + np.multiply.outer(swing, jitter)
    return JitteredFrame(image, x, y, offsets, np.column_stack([rate, np.zeros(offsets.size)]), np.append(mid, 0.0))
