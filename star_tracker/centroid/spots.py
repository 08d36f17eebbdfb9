# SPDX-License-Identifier: Apache-2.0
"""The `Spots` record passed from the centroider to the identifier."""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from numbers import Integral
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .applied_motion import AppliedMotion
    from .psf.estimate import PsfEstimate

FLAG_SATURATED = 1 << 0  # a pixel of the spot reached the saturation level
FLAG_EDGE = 1 << 1  # its window touches the image border, or its streak runs past it: not matched (identify)
FLAG_STREAK = 1 << 2  # measured with the streak model: streak_length / streak_angle are valid
FLAG_BLENDED = 1 << 3  # split from a blend with a neighbour (fitted jointly with it)
FLAG_RATE_AIDED = 1 << 4  # fitted on the smear path predicted from a known body rate

# Spots.from_xy: flux [ADU] of a magnitude-0 spot (flux = FLUX_AT_MAGNITUDE_0 10^(-0.4 m)).
FLUX_AT_MAGNITUDE_0 = 1.0e6

# Per-spot fields and the dtype kinds they accept ("f" float, "u"/"i" integer).
_FLOAT_FIELDS = ("x", "y", "flux", "snr", "peak", "streak_length", "streak_angle")
_INTEGER_FIELDS = ("flags", "area")


@dataclass(frozen=True)
class Spots:
    """
    Detected spots as parallel arrays (N entries, brightest first).

    x, y: position at mid-exposure [px], (0, 0) = centre of the top-left pixel; flux:
    background-subtracted signal [ADU]; snr: flux / its 1-sigma [-]; cov: (N, 2, 2) covariance
    of (x, y) [px^2] from the noise model; flags: FLAG_* bit set; area: detection footprint
    [px]; peak: brightest background-subtracted pixel [ADU]; streak_length: length of the
    smear over the exposure [px] (0 for point-like spots); streak_angle: its direction [rad]
    from +x toward +y (start -> end when the body rate is known, else in (-pi/2, pi/2]).
    width, height: image size [px]; background_adu, noise_adu: frame background level and
    1-sigma pixel noise [ADU]; rejected_shape: detections dropped as hot pixels or cosmic rays;
    rejected_extended: spots dropped as extended objects (far broader than the PSF: clouds,
    stray-light structure; extended_objects.py);
    rate_aid_rejected: a body rate was given but the streaks in the image disagreed with it, so
    the frame was measured without it (rate_aid.AID_* rules); psf: the frame's PSF as the
    centroider estimated or assumed it (psf.estimate.PsfEstimate; None for spots that did not
    come from an image, e.g. Spots.from_xy or a decoded message); fit_model: what the single
    point-like stars were fitted with (centroid/single_star_model.py): "gaussian" (round),
    "elliptical" (the estimate's astigmatic shape), "core_halo" (a core and up to two wider Gaussians on one
    centre, fitted to the frame's bright stars), "template" (the frame's own radial profile: rings, strong misfits);
    "" when no point star was fitted; applied_motion: the rate and acceleration the spots were
    measured with (applied_motion.AppliedMotion, set by extract_spots; None when not known:
    spots from elsewhere, or a message without the centroider's smear_aid).

    The record checks its arrays when built (every frame, so only cheap checks): numpy arrays,
    x of shape (N,) and every other per-spot array of the same length, cov (N, 2, 2), float
    dtypes for the measured values and integer ones for flags and area, width and height
    positive integers. Values are not checked: NaN and inf pass (see ros.convert.drop_invalid_spots).
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    snr: np.ndarray
    cov: np.ndarray
    flags: np.ndarray
    area: np.ndarray
    peak: np.ndarray
    width: int
    height: int
    background_adu: float = 0.0
    noise_adu: float = 0.0
    rejected_shape: int = 0
    rejected_extended: int = 0
    streak_length: np.ndarray | None = None
    streak_angle: np.ndarray | None = None
    rate_aid_rejected: bool = False
    psf: "PsfEstimate | None" = None
    fit_model: str = ""
    applied_motion: "AppliedMotion | None" = None

    def __post_init__(self) -> None:
        n = np.asarray(self.x).size
        for name in ("streak_length", "streak_angle"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.zeros(n))
        self.validate()

    def validate(self) -> None:
        """
        Raise ValueError naming the first field whose type, shape or dtype is wrong.

        Run at construction; consumers of a record that may have bypassed it, such as the
        identifier's compiled kernels, run it again.
        """
        for name in _FLOAT_FIELDS + _INTEGER_FIELDS + ("cov",):
            if not isinstance(getattr(self, name), np.ndarray):
                raise ValueError(f"Spots.{name} must be a numpy array, got {type(getattr(self, name)).__name__}")
        if self.x.ndim != 1:
            raise ValueError(f"Spots.x must have shape (N,), got {self.x.shape}")
        n = self.x.size
        for name in _FLOAT_FIELDS + _INTEGER_FIELDS:
            if getattr(self, name).shape != (n,):
                raise ValueError(f"Spots.{name} must have shape ({n},) like x, got {getattr(self, name).shape}")
        if self.cov.shape != (n, 2, 2):
            raise ValueError(f"Spots.cov must have shape ({n}, 2, 2), got {self.cov.shape}")
        for name in _FLOAT_FIELDS + ("cov",):
            if getattr(self, name).dtype.kind != "f":
                raise ValueError(f"Spots.{name} must have a float dtype, got {getattr(self, name).dtype}")
        for name in _INTEGER_FIELDS:
            if getattr(self, name).dtype.kind not in "ui":
                raise ValueError(f"Spots.{name} must have an integer dtype, got {getattr(self, name).dtype}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if not (isinstance(value, Integral) and not isinstance(value, bool) and value > 0):
                raise ValueError(f"Spots.{name} must be a positive integer [px], got {value!r}")

    def __len__(self) -> int:
        return int(self.x.size)

    @staticmethod
    def empty(width: int, height: int, **frame_values) -> "Spots":
        z = np.zeros(0)
        return Spots(z, z, z, z, np.zeros((0, 2, 2)), np.zeros(0, np.uint32), np.zeros(0, np.int32),
                     z, width, height, **frame_values)

    @staticmethod
    def from_xy(x, y, magnitude=None, *, sigma_px: float, width: int, height: int, snr: float = 100.0,
                flux_at_magnitude_0: float = FLUX_AT_MAGNITUDE_0) -> "Spots":
        """
        Return point-like spots at pixel positions x, y [px], in the order given (brightest first).

        x, y: (N,) each, (0, 0) = centre of the top-left pixel; by convention brightest first.

        magnitude: (N,) stellar magnitudes, flux = flux_at_magnitude_0 10^(-0.4 magnitude)
        [ADU] (default zero point FLUX_AT_MAGNITUDE_0); None: every spot at magnitude 0.
        sigma_px: 1-sigma position error [px], the same on both axes, uncorrelated: cov =
        sigma_px^2 I. width, height: image size [px]. snr: every spot's SNR [-]. The rest is
        what a 3x3 footprint of a PSF of ~1.3 px sigma gives: area 9 px, peak flux / 10,
        no flags, no streak.
        """
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        if magnitude is None:
            magnitude = np.zeros(x.shape)
        flux = flux_at_magnitude_0 * 10.0 ** (-0.4 * np.asarray(magnitude, dtype=float))
        n = x.size
        cov = np.tile(np.eye(2) * sigma_px ** 2, (n, 1, 1))
        return Spots(x, y, flux, np.full(n, float(snr)), cov, np.zeros(n, np.uint32), np.full(n, 9, np.int32),
                     flux / 10.0, width, height)

    def take(self, index: np.ndarray) -> "Spots":
        """Return the spots at `index` (integer or boolean), frame values kept."""
        per_spot = {f.name: getattr(self, f.name)[index] for f in fields(self)
                    if isinstance(getattr(self, f.name), np.ndarray)}
        return replace(self, **per_spot)
