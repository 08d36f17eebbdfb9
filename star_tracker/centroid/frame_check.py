# SPDX-License-Identifier: Apache-2.0
"""
Why a frame gave no usable star spots.

Blank, saturated, dominated by defects, or simply too few stars above the threshold. A short
reason for the CLI's output and a node's /diagnostics.
"""
from __future__ import annotations

import numpy as np

from .spots import Spots

SATURATED_FRACTION = 0.5  # a frame with at least this share of pixels at the clip level is saturated
DEFECT_DOMINATED_RATIO = 4.0  # defects rejected per spot kept beyond which a frame is defect-dominated


def frame_problem(image: np.ndarray, spots: Spots, min_spots: int, saturation_adu: float = 0.0) -> str | None:
    """
    Return the reason a frame (2-D, ADU) cannot be identified from `spots` (extract_spots' result).

    Or None when it holds at least `min_spots` spots. saturation_adu: the clip level [ADU] (0:
    the dtype's maximum; float images: none).
    """
    if len(spots) >= min_spots:
        return None
    finite = np.isfinite(image) if image.dtype.kind == "f" else None
    if finite is not None and not finite.any():
        return "blank frame: no finite pixel"
    values = image[finite] if finite is not None and not finite.all() else image
    clip = saturation_adu or (float(np.iinfo(image.dtype).max) if image.dtype.kind in "ui" else np.inf)
    saturated = float(np.mean(values >= clip)) if np.isfinite(clip) else 0.0
    if saturated >= SATURATED_FRACTION:
        return f"saturated frame: {saturated:.0%} of the pixels at the clip level {clip:g} ADU"
    low, high = float(values.min()), float(values.max())
    if low == high:
        return f"blank frame: every pixel is {low:g} ADU (no signal, no noise)"
    found = f"{len(spots)} star spot(s) found, at least {min_spots} needed"
    if spots.rejected_shape >= max(10.0, DEFECT_DOMINATED_RATIO * len(spots)):
        return (f"frame dominated by defects: {spots.rejected_shape} hot pixels / cosmic rays rejected, "
                f"{found}")
    return (f"too few stars: {found} (background {spots.background_adu:.1f} ADU, noise {spots.noise_adu:.2f} ADU; "
            "a lower detection threshold, or check exposure and focus)")
