# SPDX-License-Identifier: Apache-2.0
"""
The stress campaign, judged against the truth.

Its missions' draws, the frames' delivery (stamps, drops, duplicates), the bit flips, one
mission run against the rendered truth, and the summary's strata and failures.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pyarrow as pa
import pytest

from star_tracker.campaign import CampaignSpec
from star_tracker.campaign.engine import run_batch
from star_tracker.campaign.presets import KINDS
from star_tracker.campaign.presets import stress
from star_tracker.sim.render import FalseObjectModel
from star_tracker.sim.sensor import SensorModel


def test_missions_are_drawn_from_their_seed_and_cover_every_stratum():
    draws = [stress.draw_mission(np.random.default_rng([7, k]), 40, SensorModel()) for k in range(400)]
    again = stress.draw_mission(np.random.default_rng([7, 5]), 40, SensorModel())
    assert again.labels == draws[5].labels and again.schedule == draws[5].schedule
    seen = {name: {d.labels[name] for d in draws} for name in stress.MISSION_STRATA}
    assert seen["motion"] == set(stress.MOTIONS)
    assert seen["false_objects"] == set(stress.FALSE_OBJECTS)
    assert seen["detector"] == set(stress.DETECTOR)
    assert seen["psf"] == {"nominal", "defocus"} and seen["rate_aid"] == {"gyro", "identifier"}
    assert seen["temperature"] == {"nominal", "ramp"} and seen["stray_light"] == {"nominal", "high"}
    faults = {f for d in draws for f in d.frame_faults}
    assert faults == set(stress.FRAME_FAULTS)
    psf = np.array([d.psf_sigma_px for d in draws if d.psf_sigma_px != 1.0])
    assert 0.4 <= psf.min() < 0.6 and 2.8 < psf.max() <= 3.0
    rays = np.array([d.sensor.cosmic_ray_rate_per_cm2_s for d in draws if d.detector == "cosmic_rays"])
    assert 5.0 <= rays.min() and rays.max() <= 500.0  # up to 100x a quiet orbit's 5 /cm^2/s


def test_the_deliveries_carry_each_fault_as_the_nodes_would_see_it():
    rng = np.random.default_rng(3)
    deliveries, events = stress._schedule(rng, 200, stress.FRAME_FAULTS)
    frames = np.array([d[0] for d in deliveries])
    tau, clock, stamp = (np.array([d[i] for d in deliveries]) for i in (1, 2, 3))
    duplicate = np.array([d[4] for d in deliveries])
    assert np.all(np.diff(clock) > 0)  # the receiving clock never goes back
    assert set(range(200)) - set(frames.tolist())  # some frames dropped
    assert duplicate.any() and all(stamp[i] == stamp[i - 1] for i in np.flatnonzero(duplicate))
    jumps = np.diff(tau)
    assert jumps.min() < -2.0  # the loop: more than reset_after_s back
    assert jumps.max() > 1.0  # the gap
    future = stamp - clock > stress.MAX_FUTURE_S
    assert 1 <= future.sum() <= 2  # one frame (delivered twice when also duplicated)
    # Stamps are the scene's time but for the one from the future.
    assert np.count_nonzero(np.abs(stamp - stress.EPOCH_S - tau) > 1e-9) == future.sum()
    assert events and all(0 < e < len(deliveries) for e in events)


def test_bit_flips_change_exactly_the_bits_asked():
    image = np.full((64, 64), 1000, np.uint16)
    flipped = stress.flip_bits(image, 50, np.random.default_rng(1))
    changed = np.unpackbits((image ^ flipped).view(np.uint8)).sum()
    assert 40 <= changed <= 50 and changed % 2 == 50 % 2  # a bit flipped twice is back: pairs cancel
    assert np.array_equal(image, np.full((64, 64), 1000, np.uint16))  # the input is left alone


def _every_fault(frames: int):
    """Return the first schedule (seeds 0, 1, ...) with a jump back, a gap, a duplicate and a stamp from the future."""
    for seed in range(1000):
        deliveries, events = stress._schedule(np.random.default_rng(seed), frames, stress.FRAME_FAULTS)
        tau = np.array([d[1] for d in deliveries])
        if (np.diff(tau).min() < -2.5 and np.diff(tau).max() > 1.0 and any(d[4] for d in deliveries)
                and any(d[3] - d[2] > stress.MAX_FUTURE_S for d in deliveries) and len(events) >= 2):
            return deliveries, events
    raise AssertionError("no schedule with every fault")


@pytest.mark.slow
def test_a_mission_of_faults_at_rest_is_tracked_right_and_recovers_within_two_frames(database):
    from star_tracker.models.attitude import quaternion_to_matrix
    from star_tracker.sim.motion import ConstantRateMotion

    kind = KINDS["stress"]()
    options = kind.options({"frames_per_mission": 40})
    shared = kind.prepare(options)
    rng = np.random.default_rng(11)
    mission = stress.draw_mission(rng, 40, shared.sensor)
    rotation = quaternion_to_matrix(np.array([0.2, -0.4, 0.1, 0.88]))
    mission = replace(mission, motion=ConstantRateMotion(rotation, np.radians([0.2, -0.1, 0.05])),
                      motion_kind="rest", false_objects="none", objects=FalseObjectModel(), environment=None,
                      detector="nominal", bit_flips=0, sensor=SensorModel(), psf_sigma_px=1.0,
                      stray_light_e_px_s=0.0, temperature_k=(293.15, 293.15), rate_aid="identifier",
                      frame_faults=stress.FRAME_FAULTS)
    mission.schedule, mission.events = _every_fault(40)
    record, frames = stress.run_mission(shared, options, rng, mission)
    verdicts = [f["verdict"] for f in frames]
    assert {"out_of_order", "from_future", "time_reset"} <= set(verdicts)
    accepted = [f for f in frames if f["verdict"] in stress.DELIVERED_OK]
    assert all(f["solved"] and not f["wrong"] for f in accepted), [(f["frame"], f["nees"]) for f in accepted]
    assert all(f["cross_arcsec"] < 2.0 for f in accepted)
    # The loop and the gap cut the track: lost-in-space on the first frame after, tracking on the next.
    assert record["recoveries"] and all(1 <= r <= 2 for r in record["recoveries"])
    assert max(record["recoveries"]) == 2


@pytest.mark.slow
def test_a_campaign_batch_scores_its_frames_and_the_summary_counts_them_by_stratum(database):
    kind = KINDS["stress"]()
    spec = CampaignSpec("stress", trials=2, seed=2026, batch=1, options={"frames_per_mission": 6})
    table = pa.concat_tables([run_batch(kind, spec, b).table for b in range(2)])
    assert not any(table.column("error").to_pylist())
    summary = kind.summarize(table, kind.options(spec.options))
    rows = table.to_pylist()
    frames = sum(len(r["frame"]) for r in rows)
    assert summary["deliveries"] == frames == sum(summary["verdicts"].values())
    accepted = sum(v in stress.DELIVERED_OK for r in rows for v in r["verdict"])
    assert summary["frames"] == accepted
    assert sum(s["frames"] for s in summary["strata"]["phase"].values()) == accepted
    assert sum(s["frames"] for s in summary["strata"]["motion"].values()) == accepted
    wrong = sum(w for r in rows for w in r["wrong"])
    assert summary["wrong"] == wrong
    nees = [n for r in rows for n, ok in zip(r["nees"], r["solved"]) if ok]
    assert summary["nees_mean"] == pytest.approx(np.mean(nees))
    flagged = [(r["task"], f) for r in rows for f, w, n in zip(r["frame"], r["wrong"], r["nees"])
               if w or (n is not None and n > stress.NEES_997)]
    assert sorted((f["task"], f["frame"]) for f in summary["failures"]) == sorted(flagged)
    assert all(math.isfinite(f["nees"]) for f in summary["failures"])


def test_frames_on_the_command_line_are_missions_of_frames_per_mission():
    import argparse

    from star_tracker.commands.characterize import campaign_from_args

    args = argparse.Namespace(campaign="stress", trials=1001, seed=None, batch=None,
                              option=["frames_per_mission=25"])
    kind, spec = campaign_from_args(args)
    assert kind.name == "stress" and spec.trials == 41  # 41 x 25 >= 1001 frames


def test_through_nodes_is_the_stress_presets_alone():
    import argparse

    from star_tracker.commands.characterize import run_through_nodes
    from star_tracker.commands.common import CommandError

    args = argparse.Namespace(campaign="accuracy", through_nodes=True, gyro=False, trials=None, seed=None, output=None)
    with pytest.raises(CommandError, match="stress preset only"):
        run_through_nodes(args)
    with pytest.raises(CommandError, match="stress preset only"):
        run_through_nodes(argparse.Namespace(**{**vars(args), "campaign": "stress", "through_nodes": False,
                                                "gyro": True}))


def _mission_row(task: int, labels: dict, frames: list[dict]) -> dict:
    row = {"task": task, "seed": 2026, "error": "", **labels, "psf_sigma_px": 1.0, "bit_flips": 0,
           "recoveries": [2] if task == 0 else [], "frame_s": 0.03}
    for name, _ in stress.FRAME_COLUMNS:
        row[name] = [f.get(name) for f in frames]
    return row


def test_the_summary_and_its_reliability_section_count_each_stratum(tmp_path):
    from star_tracker.campaign.presets.stress_report import BEGIN, END, reliability_section, write_section

    labels = {name: "nominal" for name in stress.MISSION_STRATA}
    good = {"frame": 0, "verdict": "ok", "phase": "rest", "solved": True, "wrong": False, "wrong_star": False,
            "nees": 3.0, "cross_arcsec": 0.2}
    at_rest = [good, {**good, "frame": 1, "nees": 20.0}, {**good, "frame": 2, "verdict": "out_of_order"}]
    slewing = [{**good, "phase": "accelerating", "nees": 40.0, "wrong": True, "wrong_star": True}]
    rows = [_mission_row(0, {**labels, "motion": "rest"}, at_rest),
            _mission_row(1, {**labels, "motion": "slew"}, slewing)]
    table = pa.Table.from_pylist(rows, schema=KINDS["stress"].schema())
    summary = KINDS["stress"]().summarize(table, stress.StressOptions())
    assert summary["frames"] == 3 and summary["deliveries"] == 4 and summary["wrong"] == 1
    assert summary["wrong_star_frames"] == 1 and summary["nees_mean"] == pytest.approx(21.0)
    assert summary["strata"]["motion"]["rest"]["frames"] == 2 and summary["strata"]["motion"]["slew"]["wrong"] == 1
    assert summary["strata"]["phase"]["accelerating"]["nees_above_5_sigma"] == 1
    assert [(f["task"], f["frame"]) for f in summary["failures"]] == [(0, 1), (1, 0)]
    assert summary["recoveries"] == {"events": 1, "max_frames": 2, "not_recovered": 0, "within_2_frames": 1}
    summary.update(command="star-tracker characterize stress", machine={"cpu": "cpu", "cores": 2},
                   engine={"wall_s": 60.0}, date_utc="now")
    text = reliability_section(summary)
    assert "| motion phase (each frame, from the truth): accelerating | 1 | 0.000 | 1 | 1 | 40.00 | 100.0 % | 1 |" \
        in text
    doc = tmp_path / "RELIABILITY.md"
    doc.write_text("# Reliability\n")
    write_section(doc, text)
    write_section(doc, text)  # again: replaced, not appended twice
    assert doc.read_text().count(BEGIN) == 1 and doc.read_text().count(END) == 1


def _delivery(verdict: str, mode: str = "", solved: bool = False) -> dict:
    return {"verdict": verdict, "mode": mode, "solved": solved}


def test_recovery_counts_the_frames_the_tracker_processed_after_the_last_interruption():
    track, lis = "tracking", "lost_in_space"
    tracked = _delivery("ok", track, True)
    # A duplicate refused between the lost-in-space frame and the tracked one is no frame.
    frames = [tracked, _delivery("ok", lis, True), _delivery("out_of_order"), tracked]
    assert stress._recoveries(frames, [1], track) == [2]
    # A frame from the future, refused, neither.
    frames = [tracked, _delivery("from_future"), _delivery("ok", lis, True), tracked]
    assert stress._recoveries(frames, [1], track) == [2]
    # A loop cut short by a gap on the next frame: the gap is judged (lost-in-space, then tracked).
    frames = [tracked, _delivery("time_reset", lis, True), _delivery("ok", lis, True), tracked]
    assert stress._recoveries(frames, [1, 2], track) == [2]
    # Lost-in-space twice before tracking: 3; never tracked again: -1.
    frames = [tracked, _delivery("ok", lis, True), _delivery("ok", lis, True), tracked]
    assert stress._recoveries(frames, [1], track) == [3]
    assert stress._recoveries([tracked, _delivery("ok", "lost"), _delivery("ok", "lost")], [1], track) == [-1]
    # An interruption after a frame that was not solved cut no track.
    assert stress._recoveries([_delivery("ok", "lost"), _delivery("ok", lis, True), tracked], [1], track) == []
