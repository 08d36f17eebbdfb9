# SPDX-License-Identifier: Apache-2.0
"""
Centroiding stage: image [ADU] -> `Spots` (sub-pixel positions at mid-exposure with covariance).

The package reads as the data flow:
- extract.extract_spots runs the stage; psf_loop.PsfLoop owns the PSF loop (measure at the
  prior, estimate the PSF, measure again at the estimate);
- frame_measurement measures a frame at one PSF up to its fits: detection/ (background, noise,
  threshold, components; every detection measured as a candidate; hot pixels, clipped stars,
  extended objects, texture), tracks/ (cosmic-ray tracks merged with stars);
- frame_fits fits what the measurement kept: psf/ (the PSF estimate and the point-like stars'
  models and fits), streak/ (smeared stars: the smear a body rate predicts, the streak fits);
- records and windows hold the records passed between the steps, config the user's
  CentroidConfig, spots the `Spots` record the stage returns.
Compiled kernels (numba) sit beside the idea they serve, in *_kernel.py; warm_up compiles them.
"""
from .config import CENTROID_METHODS, CentroidConfig
from .detection.detect import estimate_background, robust_sigma
from .extract import extract_spots
from .psf.gaussian_fit import fit_gaussian_psf
from .spots import FLAG_BLENDED, FLAG_EDGE, FLAG_RATE_AIDED, FLAG_SATURATED, FLAG_STREAK, FLUX_AT_MAGNITUDE_0, Spots
from .streak.smear import SmearModel
from .windows import PsfStart

__all__ = ["CENTROID_METHODS", "FLAG_BLENDED", "FLAG_EDGE", "FLAG_RATE_AIDED", "FLAG_SATURATED", "FLAG_STREAK",
           "FLUX_AT_MAGNITUDE_0", "CentroidConfig", "PsfStart", "SmearModel", "Spots", "estimate_background",
           "extract_spots", "fit_gaussian_psf", "robust_sigma"]
