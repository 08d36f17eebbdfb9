"""Centroiding stage: image [ADU] -> `Spots` (sub-pixel positions with covariance)."""
from .extract import (CENTROID_METHODS, FLAG_EDGE, FLAG_SATURATED, CentroidConfig, Spots, estimate_background,
                      extract_spots, fit_gaussian_psf, robust_sigma)

__all__ = ["CENTROID_METHODS", "FLAG_EDGE", "FLAG_SATURATED", "CentroidConfig", "Spots", "estimate_background",
           "extract_spots", "fit_gaussian_psf", "robust_sigma"]
