# SPDX-License-Identifier: Apache-2.0
"""
Centroiding stage: image [ADU] -> `Spots` (sub-pixel positions at mid-exposure with covariance).

extract.extract_spots runs the stage: detect (background, noise, threshold, components) ->
candidates (hot-pixel cleaning, centre of gravity, shape; measure's primitives) -> saturation
(clipped spots) -> point_fits (Gaussian PSF: psf_fit, kernels; blends) / streak_spots (smeared
stars: smear, streak_free_fit (compiled: streak_free_kernel), streak_path_fit, streak_groups on
streak_model and levenberg_marquardt) -> `Spots` (spots). config holds CentroidConfig, rate_aid the body-rate
aid's check, records the records passed between the steps.
"""
from .detection.detect import estimate_background, robust_sigma
from .config import CENTROID_METHODS, CentroidConfig
from .extract import extract_spots
from .psf.gaussian_fit import fit_gaussian_psf
from .streak.smear import SmearModel
from .spots import FLAG_BLENDED, FLAG_EDGE, FLAG_RATE_AIDED, FLAG_SATURATED, FLAG_STREAK, FLUX_AT_MAGNITUDE_0, Spots

__all__ = ["CENTROID_METHODS", "FLAG_BLENDED", "FLAG_EDGE", "FLAG_RATE_AIDED", "FLAG_SATURATED", "FLAG_STREAK",
           "FLUX_AT_MAGNITUDE_0", "CentroidConfig", "SmearModel", "Spots", "estimate_background", "extract_spots",
           "fit_gaussian_psf", "robust_sigma"]
