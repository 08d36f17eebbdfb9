# SPDX-License-Identifier: Apache-2.0
"""
Spot extraction, the centroiding stage.

Detect -> measure -> reject defects and extended objects -> sub-pixel fit (points, blends,
streaks) -> `Spots`, at the PSF psf_loop.PsfLoop settles on (frame_measurement measures a
frame at one PSF, frame_fits fits it).

Input: a 2-D image in ADU (uint8/uint16/float). Output: `Spots` in pixel coordinates with
(0, 0) at the centre of the top-left pixel, sorted by flux (brightest first). Optionally a
`SmearModel` (camera + body rate + exposure) turns on rate-aided detection and fitting.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .config import CentroidConfig
from .psf_loop import PsfLoop
from .spots import Spots

if TYPE_CHECKING:
    from .streak.smear import SmearModel


def extract_spots(image: np.ndarray, config: CentroidConfig = CentroidConfig(),
                  smear: "SmearModel | None" = None, psf_prior: float | None = None, prior_rings: bool = False
                  ) -> Spots:
    """
    Detect spots and measure them (see CentroidConfig).

    `smear`, when given, predicts each star's streak from the body rate and exposure:
    detection uses the matched streak kernel and positions come from a fit on the predicted
    path (mid-exposure, curved arcs included).

    PSF (config.psf_mode "auto"; psf_loop.PsfLoop): the frame is measured with the prior width
    (`psf_prior` [px] when given, e.g. the last frames' estimate, else config.psf_sigma_px),
    its PSF estimated from the stars found (psf.estimate.estimate_psf), and, when the estimate
    differs from the prior by more than RERUN_TOLERANCE (relative), measured again with the
    estimate. A crowded frame without `psf_prior` is first measured at the prior for its
    brightest detections only (psf.pilot). `prior_rings` with `psf_prior`: the last frames'
    stars were rings (a defocused camera), so the first measurement already treats them so
    and, when the estimate agrees, is the only one. The returned Spots carry the estimate
    (`Spots.psf`, applied_sigma_px = the width used).
    """
    if image.ndim != 2 or image.size == 0:
        raise ValueError(f"expected a non-empty 2-D image, got shape {image.shape}")
    if image.dtype.kind not in "uif":
        raise ValueError(f"expected a numeric image, got dtype {image.dtype}")
    return PsfLoop(image, config, smear, psf_prior, prior_rings).run()
