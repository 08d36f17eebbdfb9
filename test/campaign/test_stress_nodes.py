# SPDX-License-Identifier: Apache-2.0
"""
The stress campaign through the real nodes: every fault kind once, the centroider and identifier processes over DDS.

A short run (a few dozen frames, every kind of fault in stress_faults.FAULT_KINDS at least
once) must account for every frame on /diagnostics, leave both nodes alive (exit code 0 after
SIGINT, no traceback) and publish no wrong attitude and no wrong guide star. The plan itself
(no ROS) is checked for what the run relies on: the same seed gives the same frames, and the
stamp rule the harness predicts with is the nodes'. No ROS mocks.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from star_tracker.campaign.stress_faults import (FAULT_KINDS, FRAME_FAULTS, MALFORMED, StampRule, flip_bits,
                                                 plan_stress)


def test_a_plan_is_its_seed_and_places_every_required_fault():
    a, b = plan_stress(40, 7, required=FAULT_KINDS), plan_stress(40, 7, required=FAULT_KINDS)
    assert [(f.t_s, f.fault, f.bad_info, f.sent, f.seed) for f in a.frames] == \
        [(f.t_s, f.fault, f.bad_info, f.sent, f.seed) for f in b.frames]
    counts = a.fault_counts()
    assert all(counts[kind] >= 1 for kind in FAULT_KINDS), counts
    assert sum(f.sent for f in a.frames) >= 40
    # Distinct stamps but for the duplicated frames' second copies.
    stamps = [f.t_s for f in a.frames if f.sent and not f.copy and f.fault != "stamp_future"]
    assert len(stamps) == len(set(stamps))


def test_the_stamp_rule_follows_the_nodes_thresholds():
    rule, now = StampRule(), 100 * 10**9
    s = 10**9
    verdicts = [rule.classify(stamp, now) for stamp in (50 * s, 51 * s, 51 * s, 50 * s, 47 * s, 48 * s, 0, now + 2 * s)]
    assert verdicts == ["ok", "ok", "out_of_order", "out_of_order", "time_reset", "ok", "unstamped", "from_future"]


def test_bit_flips_change_the_pixels_asked_for():
    image = np.full((32, 32), 100, np.uint16)
    flipped = flip_bits(image, 10, 3)
    assert np.count_nonzero(flipped != image) == 10 and np.all(image == 100)


def test_the_docs_section_goes_between_its_markers(tmp_path):
    from star_tracker.campaign.stress_nodes import BEGIN, END, write_section

    doc = tmp_path / "RELIABILITY.md"
    doc.write_text("# Reliability\n\ntext\n")
    write_section(doc, "first\n")
    write_section(doc, "second\n")
    assert doc.read_text() == f"# Reliability\n\ntext\n\n{BEGIN}\nsecond\n{END}\n"


@pytest.mark.slow
@pytest.mark.integration
def test_every_fault_through_the_nodes_is_accounted_for(tmp_path, database):  # database: built before the nodes
    pytest.importorskip("rclpy")
    from star_tracker.campaign.stress_nodes import render_section, run_stress_through_nodes

    # Short missions: every kind in about 50 frames.
    summary = run_stress_through_nodes(30, 3, tmp_path, required=FAULT_KINDS, mission_frames=(12, 20))
    print("timing [s]:", summary["timing_s"], "in all", summary["duration_s"])
    assert json.loads((tmp_path / "summary_nodes.json").read_text())["frames_sent"] == summary["frames_sent"]
    assert all(summary["faults"][kind] >= 1 for kind in FAULT_KINDS), summary["faults"]
    # Every frame sent has an outcome counted by each node it reached: nothing lost without a count.
    accounting = summary["accounting"]
    assert accounting["unaccounted"] == 0, accounting
    assert accounting["frames_without_an_outcome_seen"] == 0, accounting
    # The counters the faults must move moved by what was sent (malformed images, bad camera_info,
    # stamps from the future, out of order, time resets at each node).
    assert accounting["expected_counters_mismatched"] == {}, accounting
    sent = summary["frames_sent"]
    c, i = summary["centroider"]["counters"], summary["identifier"]["counters"]
    assert c["frames_received"] == sent and c["frames_rejected"] == sum(summary["faults"][k] for k in MALFORMED)
    assert summary["identifier"]["attitudes_seen"] == i["frames_identified"] >= sent // 2, summary["identifier"]
    # Both nodes survived every fault.
    nodes = summary["nodes"]
    assert nodes["all_alive"], nodes
    assert nodes["exit_codes"] == {"centroider": 0, "identifier": 0}, nodes
    # No wrong attitude (60", 5 sigma), no wrong guide star.
    assert summary["attitudes"]["wrong"] == 0, summary["attitudes"]["wrong_frames"]
    assert summary["stars"]["wrong_guide"] == 0, summary["stars"]
    assert summary["passed"]
    assert "every frame accounted for: **yes**" in render_section(summary)
    assert set(FRAME_FAULTS) <= set(summary["faults"])


def test_a_gyros_first_samples_under_jitter_do_not_move_the_spots(database):
    """
    The gyro run's worst frame (seed 1, mission 38, its first frame: NEES 7799, 9" off).

    A jitter mission begins; the gyro's only samples are the five inside the first exposure,
    whose slope, a 5-10 Hz swing, passed as significant and moved every spot by alpha T^2 / 24.
    As the centroider node takes them (ros/rate_input.RateSamples, the run's gyro bias, no noise),
    scored as the run scores it: against the exposure's mean attitude, with the tracker's covariance.
    """
    from star_tracker.campaign.stress_faults import FrameSource
    from star_tracker.campaign.stress_nodes import GYRO_SAMPLES, Gyro
    from star_tracker.centroid import CentroidConfig, extract_spots
    from star_tracker.centroid.streak.smear import SmearModel
    from star_tracker.identify import IdentifyConfig, make_identifier
    from star_tracker.models.attitude import matrix_to_rotation_vector
    from star_tracker.ros.rate_input import RateSamples
    from star_tracker.track.tracking import Tracker

    plan = plan_stress(2000, 1)
    mission = plan.missions[38]
    first = mission.frames[0]
    assert "jitter" in mission.motion_kind and first.sent and not first.fault
    source = FrameSource()
    rendered = source.render(mission, first)
    motion, exposure = source.motion(mission), source.sensor.exposure_s
    stamp = 1_800_000_000_000_000_000
    samples, bias = RateSamples(), Gyro(1).bias
    for offset in ((np.arange(GYRO_SAMPLES) + 0.5) / GYRO_SAMPLES - 0.5) * exposure:
        samples.add(stamp + int(round(offset * 1e9)), np.asarray(motion.angular_velocity_at(first.t_s + offset)) + bias)
    omega, alpha, verdict = samples.motion_for_frame(stamp, exposure, 0.5)
    assert verdict == "ok" and alpha is None
    spots = extract_spots(rendered.image, CentroidConfig(), SmearModel(source.camera, omega, exposure, alpha))
    result = Tracker(make_identifier("hybrid", database, IdentifyConfig())).process(stamp, spots, source.camera)
    assert result.identification.solved
    reference, phase, _ = source.reference(mission, first, rendered.truth)
    assert phase == "jitter"
    solution = result.identification.attitude
    error = matrix_to_rotation_vector(reference.T @ solution.rotation)
    nees = float(error @ np.linalg.solve(solution.covariance, error))
    assert nees < 13.9 and np.degrees(np.linalg.norm(error[:2])) * 3600 < 2.0, (nees, np.degrees(error) * 3600)


@pytest.mark.slow
@pytest.mark.integration
def test_jitter_through_the_nodes_with_a_gyro_is_published_at_mid_exposure(tmp_path, database):
    """
    A noisy, biased gyro on `imu` (5 samples per exposure): jittered frames carried to mid-exposure.

    Seed 6's three missions are jitter (two on slews). The identifier's status says which
    attitudes its gyro path carried to mid-exposure (`exposure_path`); the run judges those
    against the mid-exposure truth, the rest against the exposure's mean: none wrong.
    """
    pytest.importorskip("rclpy")
    from star_tracker.campaign.stress_nodes import run_stress_through_nodes

    summary = run_stress_through_nodes(40, 6, tmp_path, mission_frames=(12, 20), gyro=True)
    attitudes = summary["attitudes"]
    assert summary["nodes"]["all_alive"] and summary["accounting"]["unaccounted"] == 0, summary["nodes"]
    assert attitudes["on_exposure_path"]["scored"] >= 10, attitudes
    assert attitudes["wrong"] == 0, attitudes["wrong_frames"]
    assert summary["stars"]["wrong_guide"] == 0, summary["stars"]
