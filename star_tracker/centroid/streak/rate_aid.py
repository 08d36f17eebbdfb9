# SPDX-License-Identifier: Apache-2.0
"""
The rate aid: a body rate turned into the smear each star's image shows, and its check.

The smear's typical length and the detection kernel; the check that the image's streaks agree
with it.
"""
from __future__ import annotations

import numpy as np

from ..detection.candidates import Candidates
from .model import PIXEL_VARIANCE
from .smear import SmearModel, segment_length

# Rate-aid check. An aiding rate that disagrees with the image (an estimate lagging an
# acceleration, a mis-scaled or misaligned gyro) makes every path fit lock onto the same end of
# its streak: a bias common to all stars, which no attitude verification can see, with
# covariances as small as for a right aid; the rest of each streak comes out as a further spot.
# The detection footprints show the streaks as they are (the matched filter only smooths
# them), so before any fit the smear vector of each of the AID_CHECK_STREAKS brightest clean
# detections (footprint SNR >= AID_CHECK_MIN_SNR; one peak; not clipped or at the edge; minor
# second moment at most AID_CHECK_MAX_MINOR sigma^2, i.e. not two streaks side by side) is
# taken from its footprint's moments, length sqrt(12 (major - sigma^2 - 1/12)) along the major
# axis, and compared with the predicted one. When at least AID_REJECT_FRACTION of them are
# further from it than AID_TOLERANCE_PX or AID_TOLERANCE_FRACTION of their predicted length (a
# wrong rate moves all of them; streaks merged end to end or crossing others are single
# outliers), the frame is measured without the aid. On rendered frames at 0.3-5 deg/s
# (cross-boresight, roll, mixed) the right rate gives distances of 1-6 % of the length, a 10 %
# wrong one 11-17 %. With fewer than AID_CHECK_MIN_STREAKS such detections the aid is kept
# unchecked (faint fields are where it helps most).
AID_CHECK_STREAKS = 12
AID_CHECK_MIN_STREAKS = 3
AID_CHECK_MIN_SNR = 30.0
AID_CHECK_MAX_MINOR = 1.8
AID_TOLERANCE_PX = 1.0
AID_TOLERANCE_FRACTION = 0.15
AID_REJECT_FRACTION = 0.75


def rate_aid_disagrees(kept: Candidates, usable: np.ndarray, sigma: float, smear: "SmearModel") -> bool:
    """
    Return True when the footprints of the brightest candidates are not the smear `smear` predicts.

    The candidates are `kept` of those `usable` (one peak, not clipped, not at the edge); the
    tests are the AID_* above; sigma: the PSF 1-sigma [px].
    """
    one_wide = kept.minor <= AID_CHECK_MAX_MINOR * sigma ** 2  # not two streaks side by side
    snr = kept.snr
    candidates = np.flatnonzero(usable & one_wide & (snr >= AID_CHECK_MIN_SNR))
    if candidates.size < AID_CHECK_MIN_STREAKS:
        return False
    c = candidates[np.argsort(-snr[candidates], kind="stable")[:AID_CHECK_STREAKS]]
    return bool(np.mean(~footprints_as_predicted(kept, c, sigma, smear)) >= AID_REJECT_FRACTION)


def footprints_as_predicted(cand: Candidates, index: np.ndarray, sigma: float, smear: "SmearModel",
                            slack: float = 1.0, thin: bool = False) -> np.ndarray:
    """
    Return whether each candidate `index`'s footprint is the streak `smear` predicts there (bool per index).

    Its smear vector from the footprint's moments (length sqrt(12 (major - sigma^2 - 1/12))
    along the major axis) within slack x (AID_TOLERANCE_PX or AID_TOLERANCE_FRACTION of the
    predicted length) of the predicted one; sigma: the PSF 1-sigma [px]. thin: footprints
    narrower than that PSF (the width test's), whose own PSF lies anywhere in [0, sigma]: their
    length is the one in the range those PSFs give nearest the prediction.
    """
    predicted = smear.smear_vectors(cand.x[index], cand.y[index])
    predicted_length = np.linalg.norm(predicted, axis=1)
    # A pixel-integrated PSF's second moment is sigma^2 + 1/12 [px^2].
    length = np.nan_to_num(segment_length(cand.major[index], np.sqrt(sigma ** 2 + PIXEL_VARIANCE)))
    if thin:
        longest = np.nan_to_num(segment_length(cand.major[index], np.sqrt(PIXEL_VARIANCE)))
        length = np.clip(predicted_length, length, longest)
    angle = np.nan_to_num(cand.angle[index])
    measured = length[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    # A footprint has no sense (start or end): compare with the nearer of +-measured.
    distance = np.minimum(np.linalg.norm(measured - predicted, axis=1), np.linalg.norm(measured + predicted, axis=1))
    tolerance = slack * np.maximum(AID_TOLERANCE_PX, AID_TOLERANCE_FRACTION * predicted_length)
    return distance <= tolerance


def typical_smear_px(smear: "SmearModel", width: int, height: int) -> float:
    """Largest predicted smear length [px] over a 3x3 grid of field points."""
    gx, gy = np.meshgrid(np.linspace(0.1, 0.9, 3) * (width - 1), np.linspace(0.1, 0.9, 3) * (height - 1))
    return float(np.max(np.linalg.norm(smear.smear_vectors(gx.ravel(), gy.ravel()), axis=1)))


def smear_kernel(smear: "SmearModel", width: int, height: int, sigma: float, binning: int) -> np.ndarray | None:
    """
    Return the matched-filter kernel on the detection grid for a smear about the same over the field.

    That is, cross-boresight rates; None when the smear varies by more than 30 % (roll-dominated).
    """
    gx, gy = np.meshgrid(np.linspace(0.1, 0.9, 3) * (width - 1), np.linspace(0.1, 0.9, 3) * (height - 1))
    vectors = smear.smear_vectors(gx.ravel(), gy.ravel()) / binning
    mean = vectors.mean(axis=0)
    if np.max(np.linalg.norm(vectors - mean, axis=1)) > 0.3 * max(np.linalg.norm(mean), 1e-9):
        return None
    s = max(0.5, sigma / binning)
    half = int(np.ceil(0.5 * np.max(np.abs(mean)) + 2.5 * s))
    yy, xx = np.mgrid[-half:half + 1, -half:half + 1].astype(np.float64)
    kernel = np.zeros_like(xx)
    steps = max(2, int(np.ceil(np.linalg.norm(mean) * 2)))
    for t in (np.arange(steps) + 0.5) / steps - 0.5:
        kernel += np.exp(-0.5 * ((xx - t * mean[0]) ** 2 + (yy - t * mean[1]) ** 2) / s ** 2)
    return (kernel / kernel.sum()).astype(np.float32)
