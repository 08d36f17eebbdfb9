# SPDX-License-Identifier: Apache-2.0
"""The acceleration a rate-aided centroider may use: significant against its own uncertainty, or none."""
from __future__ import annotations

import math

import numpy as np

from star_tracker.sim.motion import ConstantRateMotion, JitterMotion, SlewMotion
from star_tracker.track.aid_acceleration import from_samples, significant

DEG, ARCSEC = math.pi / 180.0, math.pi / (180.0 * 3600.0)
TIMES = 1.0 - (np.arange(25) + 0.5) / 100.0  # a 100 Hz gyro's last 0.25 s
NOISE = 0.005 * DEG


def _gyro(motion, rng):
    rates = np.array([motion.angular_velocity_at(t) for t in TIMES])
    return rates + rng.normal(0.0, NOISE, rates.shape)


def test_a_slews_acceleration_is_kept_and_measured():
    rng = np.random.default_rng(1)
    motion = SlewMotion(np.eye(3), np.array([1.0, 0.5, 0.0]), math.radians(40.0), math.radians(2.0), math.radians(1.0))
    alpha, cov = from_samples(TIMES, _gyro(motion, rng))
    kept = significant(alpha, cov)
    truth = motion.axis * math.radians(1.0)
    assert kept is not None and np.linalg.norm(kept - truth) < 5 * np.sqrt(np.trace(cov))
    assert np.linalg.norm(kept - truth) < 0.05 * DEG


def test_no_acceleration_at_rest_nor_from_fast_jitter():
    rng = np.random.default_rng(2)
    at_rest = ConstantRateMotion(np.eye(3), np.radians([0.3, -0.2, 0.0]))
    jitter = JitterMotion(at_rest, np.full((1, 3), 20.0 * ARCSEC), np.array([20.0]), 0.4)
    rests = sum(significant(*from_samples(TIMES, _gyro(at_rest, rng))) is not None for _ in range(200))
    assert rests <= 6  # the chi^2 test's 1 % (binomial: 2 expected)
    assert all(significant(*from_samples(TIMES, _gyro(jitter, rng))) is None for _ in range(50))


def test_too_few_samples_or_a_bad_covariance_give_none():
    assert from_samples(TIMES[:2], np.zeros((2, 3))) == (None, None)
    assert significant(np.ones(3), None) is None
    assert significant(np.ones(3), np.zeros((3, 3))) is None
    assert significant(np.array([1.0, np.nan, 0.0]), np.eye(3)) is None
