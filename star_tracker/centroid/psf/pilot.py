# SPDX-License-Identifier: Apache-2.0
"""
The PSF estimate's pilot: a crowded frame's brightest detections, measured alone.

A frame whose PSF differs from the prior width is measured twice: at the prior, only to
estimate its PSF, then at the estimate. The estimate uses at most psf.estimate.MAX_STARS
bright isolated stars, yet a defocused photograph's thousands of detections (its rings'
fragments at the prior) were all measured at the prior. A frame with at least
PILOT_MIN_DETECTIONS detections and no running prior (extract_spots' psf_prior: a single
image, a node's first frame) measures its PILOT_DETECTIONS brightest first (highest pixel of
each footprint), with their neighbours; the rest count only as neighbours for the isolation
test, at their footprint centroids.
"""
from __future__ import annotations

import numpy as np

from ..detection.candidates import Candidates
from ..detection.detect import Detections
from ..detection.components_kernel import footprint_peaks
from .estimate import ISOLATION_SIGMAS

PILOT_DETECTIONS = 64  # 5x psf.estimate.MAX_STARS: room for clipped stars, hot pixels and close pairs
PILOT_MIN_DETECTIONS = 1500  # fewer: the large footprints the pilot measures anyway are most of the cost
CENTROID_SLACK_PX = 1.0  # a footprint centroid's distance from the measured centre, at most (about)


def pilot_detections(image: np.ndarray, det: Detections, prior_sigma: float) -> np.ndarray | None:
    """
    Return the indices of the detections the pilot measures, in detection order (None: too few to need one).

    The PILOT_DETECTIONS brightest by the highest raw value [ADU] of each footprint (the order
    of the measured peaks the estimate ranks its stars by; a centroid's neighbourhood is not: a
    ring's, or a footprint's with a neighbour in it, misses the peak), and every detection that
    may be within the isolation test's reach of one (psf.estimate.usable_stars, at prior_sigma
    [px]), so that the test sees the neighbours' measured centres, as without a pilot.
    """
    if det.x.size < PILOT_MIN_DETECTIONS:
        return None
    peak = footprint_peaks(image, det.labels, det.binning, det.label.astype(np.int64), det.left.astype(np.int64),
                           det.top.astype(np.int64), det.right.astype(np.int64), det.bottom.astype(np.int64))
    brightest = np.argsort(-peak, kind="stable")[:PILOT_DETECTIONS]
    reach = ISOLATION_SIGMAS * max(prior_sigma, 1.0) + 2.0 * CENTROID_SLACK_PX
    distance = np.hypot(det.x[brightest, None] - det.x[None, :], det.y[brightest, None] - det.y[None, :])
    return np.flatnonzero((distance <= reach).any(axis=0))


def neighbour_positions(cand: Candidates, det: Detections, pilot: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return every detection as a neighbour for the isolation test: x, y [px] and slack [px].

    The pilot's measured centres (slack 0; one whose measurement failed, NaN, is no neighbour,
    as in a full measurement); the others' footprint centroids (slack CENTROID_SLACK_PX: one
    that might be within reach counts). `cand`: the pilot's candidates, in `pilot` order.
    """
    others = np.ones(det.x.size, bool)
    others[pilot] = False
    measured = np.isfinite(cand.x) & np.isfinite(cand.y)
    slack = np.concatenate([np.zeros(int(measured.sum())), np.full(int(others.sum()), CENTROID_SLACK_PX)])
    return (np.concatenate([cand.x[measured], det.x[others]]), np.concatenate([cand.y[measured], det.y[others]]),
            slack)
