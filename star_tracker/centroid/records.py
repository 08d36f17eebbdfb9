# SPDX-License-Identifier: Apache-2.0
"""
Records passed between the steps of the centroiding stage.

What every fit reads of the frame (FitContext), the table of measured spots (SpotRows) and what
a fit returns (FitOutcome).
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import NamedTuple

import numpy as np

from .config import CentroidConfig
from .detection.detect import Detections
from .psf.elliptical import EllipticalGaussianPsf


@dataclass(frozen=True)
class FitContext:
    """
    One frame as the fits see it.

    Image [ADU] (2-D), its detections (background [ADU] on the detection grid, pixel noise
    [ADU]), the stage's config and the PSF 1-sigma the fits use [px] (config.psf_sigma_px,
    at least psf_estimate.MIN_SIGMA_PX; 0.5 without a PSF); rings: the stars are rings
    (psf_estimate.PsfEstimate.annular: blends split farther apart, config.blend_separation_px);
    own_psf: the frame's empirical PSF may replace the Gaussian (point_fits; not when a known
    body rate smears the stars: their shapes then differ across the field); elliptical: an
    astigmatic frame's PSF (elliptical_psf.EllipticalGaussianPsf, from the PSF estimate), the
    single stars' fit model unless their bright stars fit it worse than the round Gaussian
    (single_star_model; None: round).
    """

    image: np.ndarray
    det: Detections
    config: CentroidConfig
    sigma: float
    rings: bool = False
    own_psf: bool = True
    elliptical: "EllipticalGaussianPsf | None" = None

    @property
    def noise(self) -> float:
        """1-sigma pixel noise [ADU]."""
        return self.det.noise_adu

    @property
    def gain(self) -> float:
        """Gain [e-/ADU] of the shot-noise term."""
        return self.config.gain_e_per_adu


class FittedStars(NamedTuple):
    """Stars as a fit measured them, (n,) each: x, y [px], flux [ADU], cov (n, 2, 2) [px^2], snr [-]."""

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    cov: np.ndarray
    snr: np.ndarray

    def take(self, index) -> "FittedStars":
        return FittedStars(*(np.asarray(a)[index] for a in self))

    @staticmethod
    def concatenate(parts: list["FittedStars"]) -> "FittedStars":
        return FittedStars(*(np.concatenate(column) for column in zip(*parts)))


@dataclass(frozen=True)
class SpotRows:
    """
    Measured spots as parallel arrays (n entries).

    X, y [px] (mid-exposure); flux [ADU]; snr [-]; cov (n, 2, 2) covariance of (x, y) [px^2];
    flags (uint32 FLAG_* bits); length, angle: streak length [px] and direction [rad] (0 for
    point-like spots); peak: brightest background-subtracted pixel [ADU]; area: detection
    footprint [px] (0: split off a blend).
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    snr: np.ndarray
    cov: np.ndarray
    flags: np.ndarray
    length: np.ndarray
    angle: np.ndarray
    peak: np.ndarray
    area: np.ndarray

    def __len__(self) -> int:
        return int(self.x.size)

    def take(self, index: np.ndarray) -> "SpotRows":
        """Return the spots at `index` (integer or boolean)."""
        return SpotRows(**{f.name: getattr(self, f.name)[index] for f in fields(SpotRows)})

    def with_values(self, index: np.ndarray, **values) -> "SpotRows":
        """Return a copy with the named fields replaced at `index` (the others shared)."""
        changed = {}
        for name, value in values.items():
            column = getattr(self, name).copy()
            column[index] = value
            changed[name] = column
        return replace(self, **changed)

    def with_stars(self, index: np.ndarray, stars: FittedStars, **values) -> "SpotRows":
        """Return a copy with the spots at `index` replaced by the fitted `stars` (and `values`)."""
        return self.with_values(index, **stars._asdict(), **values)

    @staticmethod
    def split_off(stars: FittedStars, peak, flags: int, length=None, angle=None) -> "SpotRows":
        """
        Stars split off a blend (not detections of their own: area 0).

        Peak (n,) [ADU]; flags one FLAG_* set for all; length [px], angle [rad] (n,) for streaks,
        None: point-like.
        """
        x = np.asarray(stars.x, dtype=float)
        n = x.size
        zero = np.zeros(n)
        return SpotRows(x, np.asarray(stars.y, dtype=float), np.asarray(stars.flux, dtype=float),
                        np.asarray(stars.snr, dtype=float), np.asarray(stars.cov, dtype=float).reshape(n, 2, 2),
                        np.full(n, flags, np.uint32), zero if length is None else np.asarray(length, dtype=float),
                        zero.copy() if angle is None else np.asarray(angle, dtype=float),
                        np.asarray(peak, dtype=float), np.zeros(n, np.int64))

    @staticmethod
    def concatenate(parts: list["SpotRows"]) -> "SpotRows":
        """Return the spots of `parts`, in order."""
        return SpotRows(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(SpotRows)})


class FitOutcome(NamedTuple):
    """
    What a fit step returns.

    `spots`, the frame's spot table with the fitted values written in; `added`, further stars
    it split off (new spots); `converged`, for the spots it was asked to fit, which ones its
    fit describes (None when the step does not tell); `model`, the single stars' fit model
    (fit_points: "gaussian", "elliptical", "core_halo" or "template"; "" from other steps);
    `psf`, that model itself where it is not the round Gaussian (any object with
    sample(dx, dy), e.g. empirical_psf.EmpiricalPsf; None otherwise).
    """

    spots: SpotRows
    added: SpotRows
    converged: np.ndarray | None = None
    model: str = ""
    psf: object | None = None


def no_spots() -> SpotRows:
    """Return an empty SpotRows."""
    return SpotRows.split_off(FittedStars([], [], [], np.zeros((0, 2, 2)), []), [], 0)
