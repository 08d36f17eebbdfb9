# SPDX-License-Identifier: Apache-2.0
"""
The fused body attitude against the truth: two heads 90 deg apart, Hipparcos stars, Gaussian ray noise.

Per body axis the fused error matches a single head's cross-boresight error, while a single
head's roll error is many times larger; the stated covariance is consistent (NEES ~ 3) with
the heads exposed at other stamps than the fused one and a rate that is itself in error;
without the rate the stamp offsets would dominate. Heads: nominal 15 deg camera, Hp <= 7,
0.1 px at Hp 5 growing with magnitude (fuse_spacecraft.py). Run: pytest test/fuse -q.
"""
from __future__ import annotations

import numpy as np
import pytest

from star_tracker.fuse import BodyRate, FusionConfig, FusionState
from star_tracker.models.attitude import rotation_vector_to_matrix
from star_tracker.models.attitude_estimation import quest

from fuse_spacecraft import MOUNT_A, MOUNT_B, Sky, arcsec, error_vector, observe, random_rotation

FRAMES = 300
MS = 1_000_000  # ns


@pytest.fixture(scope="module")
def sky(catalog):
    return Sky.from_catalog(catalog)


def rms(errors: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.asarray(errors) ** 2, axis=0))


def test_two_heads_90_degrees_apart_leave_no_weak_axis(sky):
    """
    300 random attitudes, both heads at the fused stamp.

    Measured (RMS, arcsec): single head A (head frame) 0.88, 0.94 across the boresight, 8.14 in
    roll; fused (body frame) 0.85, 0.58, 0.90: every body axis within 1.5 x the single head's
    cross-boresight error (0.91), its roll 8.9 x that.
    """
    rng = np.random.default_rng(40)
    single, fused = [], []
    for _ in range(FRAMES):
        body = random_rotation(rng)
        a, b = observe(sky, "a", MOUNT_A, body, 0, rng), observe(sky, "b", MOUNT_B, body, 0, rng)
        single.append(error_vector(quest(a.rays, a.catalog_vectors, a.ray_sigmas).rotation, body @ MOUNT_A.T))
        state = FusionState(FusionConfig(("a", "b")))
        state.add(a)
        state.add(b)
        fused.append(error_vector(state.fused_at(0).rotation, body))
    single_rms, fused_rms = arcsec(rms(single)), arcsec(rms(fused))
    cross_boresight = float(np.sqrt(np.mean(single_rms[:2] ** 2)))
    print(f"\nRMS error [arcsec]: single head (x, y, roll) {np.round(single_rms, 2)}, "
          f"fused (body x, y, z) {np.round(fused_rms, 2)}")
    assert np.all(fused_rms <= 1.5 * cross_boresight), (fused_rms, single_rms)
    assert single_rms[2] >= 5.0 * cross_boresight, single_rms


def test_the_covariance_is_consistent_with_stamp_offsets_and_a_rate_error(sky):
    """
    Heads exposed 40 and 60 ms before the fused stamp, body at 1 deg/s, the rate 50 urad/s off per axis.

    The rate error turns both heads' rays alike (0.5" per axis here): the shared error the fit
    marginalises. Measured over 300 frames: NEES 3.05 with the rate's covariance; 5.23 when
    the fusion is told the rate is exact; RMS error per body axis 0.92, 0.78, 1.07" with the
    rate, 82 to 122" without it (the body turns 3 arcmin in 50 ms).
    """
    rng = np.random.default_rng(41)
    rate_sigma, told, exact, no_rate_error = 50e-6, [], [], []
    for _ in range(FRAMES):
        truth, axis = random_rotation(rng), rng.normal(size=3)
        rate = np.radians(1.0) * axis / np.linalg.norm(axis)
        measured_rate = rate + rng.normal(scale=rate_sigma, size=3)

        def at(offset_s):
            return truth @ rotation_vector_to_matrix(rate * offset_s)
        observations = [observe(sky, "a", MOUNT_A, at(-0.04), -40 * MS, rng),
                        observe(sky, "b", MOUNT_B, at(-0.06), -60 * MS, rng)]
        for body_rate, out in ((BodyRate(measured_rate, np.eye(3) * rate_sigma ** 2), told),
                               (BodyRate(measured_rate, np.zeros((3, 3))), exact), (None, no_rate_error)):
            state = FusionState(FusionConfig(("a", "b")))
            for observation in observations:
                state.add(observation)
            fused = state.fused_at(0, body_rate)
            error = error_vector(fused.rotation, truth)
            out.append((error @ np.linalg.solve(fused.covariance, error), *error))
    told, exact, no_rate_error = np.array(told), np.array(exact), np.array(no_rate_error)
    print(f"\nNEES {told[:, 0].mean():.2f} (rate told exact: {exact[:, 0].mean():.2f}); RMS error [arcsec] "
          f"{np.round(arcsec(rms(told[:, 1:])), 2)}, without the rate {np.round(arcsec(rms(no_rate_error[:, 1:])), 1)}")
    assert 2.6 < told[:, 0].mean() < 3.4
    assert exact[:, 0].mean() > 4.0
    assert np.all(arcsec(rms(no_rate_error[:, 1:])) > 50.0 * arcsec(rms(told[:, 1:])))
