# SPDX-License-Identifier: Apache-2.0
"""
The three nodes as separate processes over Fast DDS (private domain, localhost only).

Checked against the simulator's truth. No ROS mocks.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from conftest import join_isolated_ros_domain  # noqa: E402
from star_tracker.ros.pipeline import NodeProcesses, TrackerMonitor, summarize  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
FRAMES = 60
RATE_HZ = 5.0  # 200 ms per frame: headroom for this 2-core VM's slow phases (CPU steal)
ARCSEC = np.radians(1 / 3600)


@pytest.fixture
def ros_graph(monkeypatch):
    env = join_isolated_ros_domain(monkeypatch)
    yield env
    rclpy.try_shutdown()


def run_pipeline(env, tmp_path, camera_params, diagnostics: dict | None = None, remaps: dict | None = None,
                 node_params: dict | None = None):
    """
    Run FRAMES frames through the three nodes.

    `diagnostics`, when given, receives the latest /diagnostics values per status name;
    `remaps`: per node, topic -> new name; `node_params`: per node (centroider, identifier),
    parameters over config/star_tracker.yaml.
    """
    monitor = TrackerMonitor(name="integration_monitor")
    params = {"camera_simulator": {"max_frames": FRAMES, "start_delay_s": 2.0, "wait_for_subscribers": True,
                                   "rate_hz": RATE_HZ, **camera_params},
              **(node_params or {})}
    nodes = NodeProcesses(env, tmp_path / "logs", params, REPO / "config" / "star_tracker.yaml", remaps=remaps)
    try:
        nodes.start()
        nodes.wait_ready(timeout_s=120)

        # Until the camera is done (by its own count: published + skipped) and every published
        # frame's truth is in, then for the pipeline to drain.
        def camera_done() -> bool:
            camera = monitor.diagnostics.get("star_tracker/camera_simulator", {})
            published = int(camera.get("frames_published", "0"))
            return (published + int(camera.get("frames_skipped_overrun", "0")) >= FRAMES
                    and sum(f.truth is not None for f in monitor.frames.values()) >= published)
        monitor.spin_for(FRAMES / RATE_HZ + 30.0, until=camera_done)

        # Drained: no new spots or attitude for 3 s (a node behind after a host stall keeps
        # publishing its backlog until then).
        def outputs() -> int:
            return sum((f.spot_count is not None) + (f.attitude is not None) for f in monitor.frames.values())
        end = time.monotonic() + 60.0
        while time.monotonic() < end:
            before = outputs()
            monitor.spin_for(3.0)
            if outputs() == before:
                break
    finally:
        codes = nodes.stop()
    frames = [monitor.frames[ns] for ns in sorted(monitor.frames)]
    camera_diagnostics = monitor.diagnostics.get("star_tracker/camera_simulator", {})
    if diagnostics is not None:
        diagnostics.update(monitor.diagnostics)
    monitor.destroy_node()
    logs = {p.name: p.read_text() for p in (tmp_path / "logs").glob("*.log")}
    return frames, codes, logs, camera_diagnostics


def host_timing_outcomes(diagnostics: dict) -> int:
    """Frames whose outcome the host's timing explains (stalls, discovery order), by the nodes' own counters."""
    centroider = diagnostics.get("star_tracker/centroider", {})
    identifier = diagnostics.get("star_tracker/identifier", {})
    keys = ("frames_dropped_overload", "frames_bridged", "frames_not_bridged", "not_identified_timeout",
            "frames_without_camera_info")
    return int(centroider.get("frames_dropped_overload", "0")) + sum(int(identifier.get(k, "0")) for k in keys)


def counters(diagnostics: dict) -> str:
    """Each node's counters and values, one line per node (for failure messages)."""
    return "\n".join(f"{name}: " + ", ".join(f"{k}={v}" for k, v in values.items())
                     for name, values in sorted(diagnostics.items()))


@pytest.mark.integration
@pytest.mark.parametrize("rate_deg_s", [[0.0, 0.0, 0.0], [0.3, 0.4, 0.0]], ids=["at_rest", "0.5_deg_per_s"])
@pytest.mark.slow  # starts the three nodes
def test_three_nodes_track_truth(ros_graph, tmp_path, rate_deg_s):
    diagnostics: dict = {}
    frames, codes, logs, camera = run_pipeline(ros_graph, tmp_path, {"attitude.body_rate_deg_s": rate_deg_s},
                                               diagnostics)
    assert codes == {"camera_simulator": 0, "centroider": 0, "identifier": 0}, logs
    assert not any("Traceback" in text for text in logs.values()), logs
    # Stopped by SIGINT, the nodes with reliable outputs waited for their acknowledgements
    # (output_flush.py; the centroider's spots are best effort).
    for name in ("camera_simulator", "identifier"):
        assert "outputs flushed: every subscriber acknowledged" in logs[f"{name}.log"], logs[f"{name}.log"]

    truth_frames = [f for f in frames if f.truth is not None]
    # A host too slow for the schedule makes the camera skip frames (counted and logged; CI
    # with ~40 % CPU steal: 11 of 60); the pipeline is judged on the frames that exist, at least 45.
    assert camera.get("frames_published") == str(len(truth_frames)), camera  # every published frame seen
    skipped = int(camera.get("frames_skipped_overrun", "0"))
    assert len(truth_frames) + skipped == FRAMES, camera
    assert len(truth_frames) >= 45, logs["camera_simulator.log"]
    # Every output carries the stamp of a frame the simulator rendered: joins are exact.
    assert all(f.truth is not None for f in frames if f.attitude is not None or f.spot_count is not None)
    stamps = np.array([f.stamp_ns for f in truth_frames])
    period_ns = int(round(1e9 / RATE_HZ))
    assert np.all(np.diff(stamps) % period_ns == 0) and np.all(np.diff(stamps) > 0)  # exact mid-exposure grid

    summary = summarize(frames)
    # With the shipped settings a host stall has counted outcomes: frames dropped for overload
    # (queue_depth 3 rides out ~3 frames), frames bridged during a stalled lost-in-space solve
    # (only the newest is published), solves out of time, and spots ahead of the identifier's
    # first camera_info (discovery). Those are accounted for; every other frame is identified.
    timed_out = host_timing_outcomes(diagnostics)
    # This host once dropped 13 of 60 at rest for overload while its CPU was being stolen.
    assert len(truth_frames) - timed_out >= 30, counters(diagnostics)
    good = [f for f in truth_frames if f.attitude is not None and f.error()[0] < 30 * ARCSEC]
    assert len(good) >= 0.95 * (len(truth_frames) - timed_out), f"{summary}\n{counters(diagnostics)}"
    assert summary["wrong_over_60_arcsec"] == 0, summary

    # The published covariance and matched stars agree with what the simulator rendered.
    for f in truth_frames:
        if f.attitude is None:
            continue
        assert f.covariance is not None and np.all(np.linalg.eigvalsh(f.covariance) > 0)
        truth_stars = f.truth_objects[f.truth_objects["kind"] == 0]
        assert f.matched is not None and f.matched.size >= 5
        d = np.hypot(f.matched["pixel_x"][:, None] - truth_stars["pixel_x"][None],
                     f.matched["pixel_y"][:, None] - truth_stars["pixel_y"][None])
        nearest = truth_stars["hip_id"][d.argmin(axis=1)]
        assert np.mean(nearest == f.matched["hip_id"]) >= 0.95
        assert np.all(f.matched["residual"] < 10 * ARCSEC * 53)


def test_the_monitor_keeps_the_newest_identified_frames_image(ros_graph):
    """
    The demo's picture needs an identified frame's image.

    After a host stall the newest 8 images (all the monitor keeps) can all belong to frames
    not identified yet.
    """
    from star_tracker.ros import convert

    monitor = TrackerMonitor(name="image_keeping_monitor")
    try:
        image = np.zeros((8, 8), np.uint16)
        stamps = [1_000_000_000 + k * 100_000_000 for k in range(20)]
        for k, stamp in enumerate(stamps):
            monitor._on_image(convert.array_to_image(image + k, stamp, "f"))
            if k == 5:  # identified; the frames after it are not (yet)
                monitor.frames[stamp].matched = np.zeros(3, convert.MATCH_DTYPE)
        kept = [ns for ns in stamps if monitor.frames[ns].image is not None]
        assert kept == [stamps[5]] + stamps[-8:]
        assert monitor.frames[stamps[5]].image[0, 0] == 5
    finally:
        monitor.destroy_node()
