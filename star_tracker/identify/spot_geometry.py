# SPDX-License-Identifier: Apache-2.0
"""SpotGeometry: one frame's spots as every identification algorithm and the deep re-match read them."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models.camera import CameraModel


@dataclass
class SpotGeometry:
    """
    Per-frame quantities algorithms share, for the flux-sorted spots (base.StarIdentifier.prepare).

    rays (N, 3) unit vectors in the sensor frame; sigma (N,) 1-sigma direction error [rad]
    for matching (floored at centroid_sigma_floor_px: pattern tolerances, verification
    radius); pattern_count: how many of the brightest spots may form patterns; magnitude (N,)
    instrumental magnitude -2.5 log10(flux) [mag] with an unknown zero point (NaN where flux
    <= 0); x, y (N,) pixel positions [px]; pixel_cov (N, 2, 2) each spot's own covariance
    [px^2] (the centroider's, not floored; unknown counts as 1 px^2) and jacobian (N, 3, 2) d
    ray / d pixel [rad/px] (ray_jacobian): the weights of the final attitude fit and its
    published covariance (None: isotropic, sigma); camera: the camera the rays are of (the
    deep re-match projects stars with it; None: no deep re-match).
    """

    rays: np.ndarray
    sigma: np.ndarray
    pattern_count: int
    magnitude: np.ndarray
    x: np.ndarray
    y: np.ndarray
    pixel_cov: np.ndarray | None = None
    jacobian: np.ndarray | None = None
    camera: CameraModel | None = None
