# SPDX-License-Identifier: Apache-2.0
"""
Compile (or load from numba's on-disk cache) every compiled kernel of the centroider now, not on the first frame.

Each kernel module warms its own kernels with the argument types the centroider passes them.
"""
from __future__ import annotations


def warm_up() -> None:
    """Compile (or load) every centroid kernel: detection, point windows, PSF fits, peak shapes, streak fit."""
    from .detection import components_kernel, hot_pixel_kernel, point_window_kernel
    from .psf import blend_fit_kernel, elliptical_fit_kernel, gaussian_fit_kernel, width_fit_kernel
    from .streak import free_fit_kernel
    from .tracks import peak_shape_kernel

    for kernel in (gaussian_fit_kernel, components_kernel, blend_fit_kernel, elliptical_fit_kernel, width_fit_kernel,
                   peak_shape_kernel, point_window_kernel, hot_pixel_kernel, free_fit_kernel):
        kernel.warm_up()
