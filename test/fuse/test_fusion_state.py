# SPDX-License-Identifier: Apache-2.0
"""
FusionState as a node drives it: what is accepted, left out, rejected, dropped and re-admitted, and that all is counted.

Observations come from the simulated two-head spacecraft (fuse_spacecraft.py) over the
Hipparcos sky.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from star_tracker.fuse import (AlignmentConfig, AlignmentFilter, BodyRate, FusionConfig, FusionState,
                               FusionUnavailable)
from star_tracker.models.attitude import ARCSEC

from fuse_spacecraft import MOUNT_A, MOUNT_B, Sky, error_vector, observe, random_rotation

MS = 1_000_000  # ns


@pytest.fixture(scope="module")
def sky(catalog):
    return Sky.from_catalog(catalog)


@pytest.fixture()
def scene(sky):
    """Return (body rotation, observation of head a, of head b) at stamp 0 of a random attitude."""
    rng = np.random.default_rng(21)
    body = random_rotation(rng)
    return body, observe(sky, "a", MOUNT_A, body, 0, rng), observe(sky, "b", MOUNT_B, body, 0, rng)


def two_heads(**settings) -> FusionState:
    return FusionState(FusionConfig(("a", "b"), **settings))


def test_both_heads_fuse_into_the_true_body_attitude(scene):
    body, a, b = scene
    state = two_heads()
    assert state.add(a).accepted and state.add(b).accepted
    fused = state.fused_at(0)
    assert fused.heads == ("a", "b") and fused.dropped == {}
    assert np.max(np.abs(error_vector(fused.rotation, body))) < 5 * ARCSEC
    assert set(fused.residuals) == {"a", "b"} and fused.residuals["a"].stars == len(a.rays)
    assert state.counters.accepted == 2 and state.counters.fused == 1


def test_an_unknown_head_is_rejected_and_counted(scene):
    state = two_heads()
    admission = state.add(replace(scene[1], head="c"))
    assert (admission.accepted, admission.rejection) == (False, "unknown_head")
    assert "'c' is not configured" in admission.detail and state.counters.unknown_head == 1


def test_stars_with_nans_are_left_out_and_counted(scene):
    _, a, _ = scene
    rays = a.rays.copy()
    rays[:5, 1] = np.nan
    sigmas = a.ray_sigmas.copy()
    sigmas[5] = 0.0
    state = two_heads()
    admission = state.add(replace(a, rays=rays, ray_sigmas=sigmas))
    assert admission.accepted and admission.detail == "6 stars left out"
    assert state.counters.excluded_stars == 6 and len(state.latest("a").rays) == len(a.rays) - 6


def test_too_few_stars_are_rejected_with_the_count(scene):
    _, a, _ = scene
    rays = a.rays.copy()
    rays[2:] = np.nan
    state = two_heads()
    admission = state.add(replace(a, rays=rays))
    assert admission.rejection == "too_few_stars" and "2 usable stars" in admission.detail
    assert state.counters.too_few_stars == 1 and state.counters.excluded_stars == len(a.rays) - 2
    assert state.latest("a") is None


@pytest.mark.parametrize("change, words", [
    (dict(mounting=np.diag([1.0, 1.0, -1.0])), "mounting is not a rotation: a reflection"),
    (dict(mounting=np.eye(3) * 1.01), "mounting is not a rotation: not orthonormal"),
    (dict(stamp_ns=0.5), "stamp_ns must be an integer"),
    (dict(head_rotation=np.eye(3)), "come together"),
    (dict(head_rotation=np.eye(3), head_covariance=-np.eye(3)), "positive definite"),
    (dict(ray_sigmas=np.ones(2)), "must be (M, 3), (M, 3), (M,)"),
])
def test_a_malformed_observation_is_rejected_with_the_reason(scene, change, words):
    state = two_heads()
    admission = state.add(replace(scene[1], **change))
    assert admission.rejection == "invalid" and words in admission.detail and state.counters.invalid == 1


def test_a_stamp_not_after_the_heads_last_is_rejected(scene):
    _, a, _ = scene
    state = two_heads()
    assert state.add(replace(a, stamp_ns=100 * MS)).accepted
    for stamp in (100 * MS, 50 * MS):
        assert state.add(replace(a, stamp_ns=stamp)).rejection == "out_of_order"
    assert state.counters.out_of_order == 2 and state.latest("a").stamp_ns == 100 * MS


def test_a_stale_head_is_dropped_reported_and_readmitted_when_it_returns(scene):
    body, a, b = scene
    state = two_heads(stale_after_s=0.3)
    state.add(a)
    state.add(b)
    assert state.fused_at(0).heads == ("a", "b")
    state.add(replace(a, stamp_ns=500 * MS))
    fused = state.fused_at(500 * MS)
    assert fused.heads == ("a",) and "stale: latest observation +0.500 s" in fused.dropped["b"]
    assert state.counters.stale == 1
    state.add(replace(b, stamp_ns=550 * MS))
    state.add(replace(a, stamp_ns=600 * MS))
    fused = state.fused_at(600 * MS)
    assert fused.heads == ("a", "b") and fused.dropped == {} and state.counters.readmitted == 1
    assert np.max(np.abs(error_vector(fused.rotation, body))) < 5 * ARCSEC


def test_a_head_whose_frames_fail_is_reported_with_its_last_rejection(scene):
    _, a, b = scene
    state = two_heads(stale_after_s=0.3)
    state.add(a)
    state.add(replace(b, stamp_ns=400 * MS, rays=b.rays[:2], catalog_vectors=b.catalog_vectors[:2],
                      ray_sigmas=b.ray_sigmas[:2]))
    fused = state.fused_at(100 * MS)
    assert fused.heads == ("a",)
    assert fused.dropped["b"].startswith("no observation yet; last one rejected")
    assert "2 usable stars" in fused.dropped["b"]
    assert state.counters.missing == 1


def test_a_head_seen_for_the_first_time_is_not_a_readmission(scene):
    _, a, b = scene
    state = two_heads()
    state.add(a)
    assert state.fused_at(0).heads == ("a",)
    state.add(b)
    assert state.fused_at(0).heads == ("a", "b") and state.counters.readmitted == 0


@pytest.mark.parametrize("rate, words", [
    (BodyRate(np.array([0.0, np.nan, 0.0]), np.zeros((3, 3))), "rate must be 3 finite values"),
    (BodyRate(np.zeros(3), -np.eye(3)), "rate covariance is not positive semi-definite"),
    (BodyRate(np.zeros(2), np.zeros((3, 3))), "rate must be 3 finite values"),
])
def test_an_unusable_rate_is_an_error(scene, rate, words):
    state = two_heads()
    state.add(scene[1])
    with pytest.raises(ValueError, match=words):
        state.fused_at(0, rate)
    with pytest.raises(ValueError, match="integer"):
        state.fused_at(0.0)


def test_no_fresh_head_is_an_error_with_the_reasons(scene):
    state = two_heads()
    state.add(scene[1])
    with pytest.raises(FusionUnavailable, match="no fresh head") as raised:
        state.fused_at(2000 * MS)
    assert set(raised.value.dropped) == {"a", "b"} and state.counters.unavailable == 1


def test_each_observation_feeds_the_alignment_filter_once(scene):
    _, a, b = scene
    alignment = AlignmentFilter(AlignmentConfig(("a", "b"), drift_psd=0.0))
    state = FusionState(FusionConfig(("a", "b")), alignment)
    state.add(a)
    state.add(b)
    state.fused_at(0)
    state.fused_at(10 * MS)  # the same two observations: no second update
    assert alignment.counters.updates == 1
    state.add(replace(a, stamp_ns=100 * MS))
    state.fused_at(100 * MS)  # only a is new
    assert alignment.counters.updates == 1
    state.add(replace(b, stamp_ns=110 * MS))
    state.fused_at(110 * MS)
    assert alignment.counters.updates == 2


@pytest.mark.parametrize("settings", [dict(heads=()), dict(heads=("a", "a")), dict(heads=("a",), stale_after_s=0.0),
                                      dict(heads=("a",), min_stars_per_head=1)])
def test_invalid_settings_are_refused(settings):
    with pytest.raises(ValueError):
        FusionConfig(**settings)


def test_an_alignment_filter_for_other_heads_is_refused():
    with pytest.raises(ValueError, match="differ"):
        FusionState(FusionConfig(("a", "b")), AlignmentFilter(AlignmentConfig(("a", "c"), drift_psd=0.0)))
