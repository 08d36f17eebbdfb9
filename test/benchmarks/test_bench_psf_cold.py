# SPDX-License-Identifier: Apache-2.0
"""
The cold-frame benchmark's rate-aided streak frames (bench/bench_psf_cold.py: alt_streak_frame).

The frame's truth is where its streaks are: the rate it hands the centroider smears a star
STREAK_PX along the rendered direction, and measured with that rate at a PSF the fits handle
well (1 px, bright), every scored star is kept and its position lies within its stated
covariance; the position chi^2 the report gives is the one the spots' covariances state.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_psf_cold as bench  # noqa: E402
from star_tracker.centroid import CentroidConfig, extract_spots  # noqa: E402


def test_a_streak_frames_rate_smears_its_stars_as_rendered_and_its_truth_is_where_they_are():
    image, x, y, snr, dx, dy, extent, smear = bench.alt_streak_frame(1.0, 30000.0, 1)
    vectors = smear.smear_vectors(x, y)
    assert np.allclose(np.hypot(*vectors.T), bench.STREAK_PX, rtol=0.02)
    spots = extract_spots(image, CentroidConfig(), smear)
    scored = bench.scored_stars(x, y, snr, dx, dy, extent, 1.0)
    assert scored.sum() >= 50
    stars, share = bench.kept_share(spots, x, y, snr, dx, dy, extent, 1.0)
    assert stars == scored.sum() and share == 1.0
    # The rendered direction: each kept star's streak lies along its smear vector (either sense).
    near = np.argmin(np.hypot(x[:, None] - spots.x[None], y[:, None] - spots.y[None]), axis=1)
    angle = np.arctan2(vectors[:, 1], vectors[:, 0])
    turned = np.abs(np.angle(np.exp(2j * (spots.streak_angle[near] - angle)))) / 2.0
    assert np.median(turned) < np.radians(2.0)
    chi2 = bench.position_chi2(spots, x, y, scored, 1.0)
    assert len(chi2) == scored.sum() and np.mean(chi2) == pytest.approx(2.0, abs=1.0)
