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

from .config import CentroidConfig, window_half
from .detection.detect import Detections
from .psf.elliptical import EllipticalGaussianPsf
from .psf.estimate import MIN_SIGMA_PX


@dataclass(frozen=True)
class PsfTrial:
    """
    A PSF a frame is measured with (psf_loop.PsfLoop tries one or more per frame).

    sigma_px: its 1-sigma width [px] (0: no PSF); rings: the stars are rings
    (PsfEstimate.annular: a spot's maxima are one star, split as a blend only farther apart);
    narrowest_px: an elongated PSF's minor-axis 1-sigma [px], the width test's (None: sigma_px);
    elliptical: an astigmatic PSF, the single stars' fit model (None: the round Gaussian).
    """

    sigma_px: float
    rings: bool = False
    narrowest_px: float | None = None
    elliptical: "EllipticalGaussianPsf | None" = None

    @property
    def model_sigma_px(self) -> float:
        """The width the detection kernel and the fits use [px]: sigma_px, at least MIN_SIGMA_PX; 0.5 without a PSF."""
        return max(self.sigma_px, MIN_SIGMA_PX) if self.sigma_px > 0 else 0.5


@dataclass(frozen=True)
class FitContext:
    """
    One frame as the fits see it.

    Image [ADU] (2-D), its detections (background [ADU] on the detection grid, pixel noise
    [ADU]), the stage's config and the PSF 1-sigma the fits use [px] (PsfTrial.model_sigma_px
    of the width tried); rings: the stars are rings (estimate.PsfEstimate.annular: blends split
    farther apart, config.blend_separation_px); own_psf: the frame's empirical PSF may replace
    the Gaussian (point_fits; not when a known body rate smears the stars: their shapes then
    differ across the field); elliptical: an astigmatic frame's PSF
    (elliptical.EllipticalGaussianPsf, from the PSF estimate), the
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

    @property
    def window_half(self) -> int:
        """Half size of a point-spot window [px] at this PSF (config.window_half)."""
        return window_half(self.sigma)

    def local_noise_factor(self, x, y, flux) -> np.ndarray:
        """
        Variance ratio of a spot's measurement under the local pixel noise vs the frame's typical one.

        (F/g + N s_local^2) / (F/g + N s^2), N = 4 pi sigma^2 the PSF's effective pixels; x, y
        [px], flux [ADU] per spot.
        """
        det = self.det
        scale = det.noise_scale_at(np.nan_to_num(x), np.nan_to_num(y))
        shot = np.maximum(np.nan_to_num(flux), 0.0) / self.gain
        pixels = 4.0 * np.pi * self.sigma ** 2 * det.noise_adu ** 2
        return (shot + pixels * scale ** 2) / (shot + pixels)


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
    sample(dx, dy), e.g. psf.empirical.EmpiricalPsf; None otherwise).
    """

    spots: SpotRows
    added: SpotRows
    converged: np.ndarray | None = None
    model: str = ""
    psf: object | None = None


def no_spots() -> SpotRows:
    """Return an empty SpotRows."""
    return SpotRows.split_off(FittedStars([], [], [], np.zeros((0, 2, 2)), []), [], 0)
