# SPDX-License-Identifier: Apache-2.0
"""
The PSF: its estimate from the frame, its models and their fits.

estimate (the PSF measured on the frame; width_fit_kernel compiled), pilot (a crowded
frame's brightest detections first), running_prior (the width carried from frame to frame);
the models fitted to point-like stars: gaussian_fit (round Gaussian; gaussian_fit_kernel and,
for blends, blend_fit_kernel compiled), elliptical (astigmatic; elliptical_fit_kernel),
core_halo (a core with wider halos), empirical (the frame's own profile);
single_star_model chooses among them per frame; point_fits fits single, blended and clipped
point-like spots. profile_kernel and matrix_kernel are the compiled fits' shared pieces.
"""
