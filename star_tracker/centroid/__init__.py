"""Centroiding stage: image [ADU] -> `Spots` (sub-pixel positions at mid-exposure with covariance).

detect (background, noise, threshold, components) -> measure (hot-pixel cleaning, centre of
gravity, shape) -> psf_fit (Gaussian PSF, blends) / streak (smeared stars) -> `Spots`.
"""
from .detect import estimate_background, robust_sigma
from .config import CENTROID_METHODS, CentroidConfig
from .extract import extract_spots
from .psf_fit import fit_gaussian_psf
from .spots import FLAG_BLENDED, FLAG_EDGE, FLAG_RATE_AIDED, FLAG_SATURATED, FLAG_STREAK, FLUX_AT_MAGNITUDE_0, Spots

__all__ = ["CENTROID_METHODS", "FLAG_BLENDED", "FLAG_EDGE", "FLAG_RATE_AIDED", "FLAG_SATURATED", "FLAG_STREAK",
           "FLUX_AT_MAGNITUDE_0", "CentroidConfig", "Spots", "estimate_background", "extract_spots",
           "fit_gaussian_psf", "robust_sigma"]
