# SPDX-License-Identifier: Apache-2.0
"""
Detection and the measurement of every detection before any fit.

detect (background, noise, threshold, connected components; components_kernel compiled),
candidates (per detection: hot pixels cleaned, centre of gravity, shape, peaks;
point_window_kernel compiled) on measure's window primitives (hot_pixel_kernel compiled),
saturation (clipped spots), sharp_pixels (hot pixels on a wide star's light, left out of its
fit), extended_objects (clouds, a lit limb: no star), texture (elongated spots pointing every
way, not smear).
"""
