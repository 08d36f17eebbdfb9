# SPDX-License-Identifier: Apache-2.0
"""
Cosmic-ray tracks merged with stars in one footprint.

track_peaks (finding the star's peak and the track's), peak_shape (the width test per peak;
peak_shape_kernel compiled), beside_tracks (such stars refitted with the frame's own PSF).
"""
