# SPDX-License-Identifier: Apache-2.0
"""
Spot extraction, the centroiding stage.

Detect -> measure -> reject defects and extended objects -> sub-pixel fit (points, blends,
streaks) -> `Spots`, at the PSF psf_loop.PsfLoop settles on (frame_measurement measures a
frame at one PSF, frame_fits fits it).

Input: a 2-D image in ADU (uint8/uint16/float). Output: `Spots` in pixel coordinates with
(0, 0) at the centre of the top-left pixel, sorted by flux (brightest first). Optionally a
`SmearModel` (camera + body rate + exposure, and the angular acceleration when known) turns on
rate-aided detection and fitting, and puts every spot at its mid-exposure position.
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from .applied_motion import AppliedMotion
from .config import CentroidConfig
from .psf_loop import PsfLoop
from .spots import FLAG_RATE_AIDED, Spots

if TYPE_CHECKING:
    from .streak.smear import SmearModel


def extract_spots(image: np.ndarray, config: CentroidConfig = CentroidConfig(),
                  smear: "SmearModel | None" = None, psf_prior: float | None = None, prior_rings: bool = False
                  ) -> Spots:
    """
    Detect spots and measure them (see CentroidConfig).

    `smear`, when given, predicts each star's streak from the body rate and exposure:
    detection uses the matched streak kernel and positions come from a fit on the predicted
    path (mid-exposure, curved arcs included). With the smear's angular acceleration the path
    is the accelerated one (samples evenly spaced in time, so the fit still gives the
    mid-exposure position), and the spots not fitted on it (point-like: predicted smear below
    config.min_smear_px, or the aid rejected) are moved from their exposure-average position
    to the mid-exposure one by SmearModel.exposure_mean_offset (alpha T^2 / 24 of the
    rotation).

    PSF (config.psf_mode "auto"; psf_loop.PsfLoop): the frame is measured with the prior width
    (`psf_prior` [px] when given, e.g. the last frames' estimate, else config.psf_sigma_px),
    its PSF estimated from the stars found (psf.estimate.estimate_psf), and, when the estimate
    differs from the prior by more than RERUN_TOLERANCE (relative; a round one by more than
    ROUND_RERUN_TOLERANCE when its uncertainty resolves that, psf_loop._remeasured), measured
    again with the estimate. A crowded frame without `psf_prior` is first measured at the prior for its
    brightest detections only (psf.pilot). `prior_rings` with `psf_prior`: the last frames'
    stars were rings (a defocused camera), so the first measurement already treats them so
    and, when the estimate agrees, is the only one. The returned Spots carry the estimate
    (`Spots.psf`, applied_sigma_px = the width used) and what was applied of `smear`
    (`Spots.applied_motion`).
    """
    if image.ndim != 2 or image.size == 0:
        raise ValueError(f"expected a non-empty 2-D image, got shape {image.shape}")
    if image.dtype.kind not in "uif":
        raise ValueError(f"expected a numeric image, got dtype {image.dtype}")
    spots = PsfLoop(image, config, smear, psf_prior, prior_rings).run()
    if smear is not None and smear.angular_acceleration_rad_s2 is not None:
        spots = to_mid_exposure(spots, smear)
    return replace(spots, applied_motion=AppliedMotion.of(smear, spots.rate_aid_rejected))


def to_mid_exposure(spots: Spots, smear: "SmearModel") -> Spots:
    """
    Return `spots` with the positions not fitted on the smear path moved to mid-exposure.

    A point-like fit (and a free streak's, approximately) measures the exposure-average
    position; the mid-exposure one is that minus smear.exposure_mean_offset. Rate-aided spots
    (FLAG_RATE_AIDED) are already at mid-exposure.
    """
    move = np.flatnonzero((np.asarray(spots.flags) & FLAG_RATE_AIDED) == 0)
    if move.size == 0:
        return spots
    x, y = np.array(spots.x, dtype=float), np.array(spots.y, dtype=float)
    finite = move[np.isfinite(x[move]) & np.isfinite(y[move])]
    if finite.size == 0:
        return spots
    offset = smear.exposure_mean_offset(x[finite], y[finite])
    # The offset at the measured (average) position is the one at mid-exposure to < 1e-3 px.
    ok = np.all(np.isfinite(offset), axis=1)
    x[finite[ok]] -= offset[ok, 0]
    y[finite[ok]] -= offset[ok, 1]
    return replace(spots, x=x.astype(np.asarray(spots.x).dtype), y=y.astype(np.asarray(spots.y).dtype))
