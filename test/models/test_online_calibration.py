# SPDX-License-Identifier: Apache-2.0
"""
Online f, k1 refinement (models/online_calibration.py) on identifications of projected stars.

A camera whose focal length drifted 0.3 % and with k1 = 0.05 that the nominal model lacks.
"""
import math

import numpy as np
import pytest

from star_tracker.identify.base import Identification
from star_tracker.models.attitude import radec_roll_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.models.online_calibration import OnlineCalibration, OnlineCalibrationConfig
from star_tracker.centroid.spots import Spots

NOMINAL = CameraModel.from_fov(1024, 1024, math.radians(15.0))
TRUE = CameraModel(1024, 1024, NOMINAL.fx * 1.003, NOMINAL.fy * 1.003, NOMINAL.cx, NOMINAL.cy, (0.05, 0, 0, 0, 0))


def solved_frame(catalog, rng, sigma_px: float = 0.1):
    """Spots of the true camera at a random pointing and their 'identification' (truth matches)."""
    rotation = radec_roll_to_matrix(rng.uniform(0, 2 * math.pi), rng.uniform(-1.2, 1.2), rng.uniform(-3, 3))
    vectors = catalog.brighter_than(6.5).unit_vectors()
    u, v, front = TRUE.project(vectors @ rotation)
    seen = np.flatnonzero(front & TRUE.in_image(u, v, margin=3.0))
    spots = Spots.from_xy(u[seen] + rng.normal(0, sigma_px, seen.size), v[seen] + rng.normal(0, sigma_px, seen.size),
                          sigma_px=sigma_px, width=1024, height=1024)
    ident = Identification("solved", "truth", "test", 0.0, spot_index=np.arange(seen.size), hip=np.arange(seen.size),
                           star_vectors=vectors[seen], attitude=_Attitude(rotation))
    return spots, ident


class _Attitude:  # the one field of AttitudeSolution that from_identification reads
    def __init__(self, rotation):
        self.rotation = rotation


def test_accumulates_refits_and_applies_only_a_constrained_estimate(catalog):
    rng = np.random.default_rng(3)
    online = OnlineCalibration(OnlineCalibrationConfig(frames_per_fit=5, max_frames=10))
    estimates = [online.add(*solved_frame(catalog, rng), NOMINAL) for k in range(10)]
    assert [e is not None for e in estimates] == [False] * 4 + [True] + [False] * 4 + [True]
    assert online.fits == 2 and len(online.frames) == 10
    estimate = online.estimate
    assert abs(estimate.value["f"] - TRUE.fx) <= 3 * estimate.sigma["f"]
    assert abs(estimate.value["k1"] - 0.05) <= 3 * estimate.sigma["k1"]
    assert set(online.applied) == {"f", "k1"}  # 10 frames: both well inside the 0.3 px rule
    refined = online.camera_for(NOMINAL)
    assert refined.fx == pytest.approx(estimate.value["f"])
    assert refined.distortion[0] == pytest.approx(estimate.value["k1"])
    assert online.camera_for(TRUE) is TRUE  # not the nominal camera of the estimate: untouched


def test_a_loose_estimate_is_not_applied_and_a_new_camera_resets(catalog):
    rng = np.random.default_rng(5)
    online = OnlineCalibration(OnlineCalibrationConfig(frames_per_fit=1, apply_corner_sigma_px=1e-4))
    online.add(*solved_frame(catalog, rng, sigma_px=0.5), NOMINAL)
    assert online.estimate is not None and online.applied == ()
    assert online.camera_for(NOMINAL) is NOMINAL
    other = CameraModel.from_fov(1024, 1024, math.radians(15.5))
    online.add(*solved_frame(catalog, rng), other)
    assert online.nominal == other and len(online.frames) == 1
