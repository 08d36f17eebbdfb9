# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker` command line.

`star-tracker demo` (here) is what `make demo` runs; the other subcommands are in
star_tracker/commands/: `record`, `play`, `info` and `reindex` handle rosbag2 bags (commands/bags.py,
docs/RECORD_REPLAY.md), then render, solve, calibrate, database, monitor, bench.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from .commands.demo_setup import default_params_file, prepare_catalog_and_database

SCENARIOS = {
    # camera_simulator parameter overrides; everything else is the default configuration.
    "default": {"attitude.profile": "constant_rate", "attitude.body_rate_deg_s": [0.3, 0.4, 0.05]},
    "rest": {"attitude.profile": "fixed"},
    "fast": {"attitude.profile": "constant_rate", "attitude.body_rate_deg_s": [1.2, 0.9, 0.2]},
    "slew": {"attitude.profile": "slew", "attitude.slew.axis": [0.6, 0.8, 0.0], "attitude.slew.angle_deg": 20.0,
             "attitude.slew.max_rate_deg_s": 2.0, "attitude.slew.accel_deg_s2": 0.5, "attitude.slew.start_s": 3.0},
    "tumble": {"attitude.profile": "tumble", "attitude.tumble.initial_rate_deg_s": [0.4, 0.2, 1.0],
               "attitude.tumble.inertia_kg_m2": [10.0, 12.0, 8.0]},
    "jitter": {"attitude.profile": "jitter", "attitude.body_rate_deg_s": [0.1, 0.0, 0.0],
               "attitude.jitter.amplitudes_rad": [5e-5, 5e-5, 2e-5], "attitude.jitter.frequencies_hz": [3.0]},
}


def cmd_demo(args: argparse.Namespace) -> int:
    """
    `star-tracker demo`: the three nodes on a scenario, one status line per frame, then a summary and the output files.

    Exit code 0 when every node exited cleanly, frames arrived and a picture was written.
    """
    if args.scenario == "leo":  # N heads in orbit and their fusion: commands/orbit_demo.py
        from .commands.orbit_demo import run_orbit_demo

        return run_orbit_demo(args)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    print(f"star_tracker demo: scenario '{args.scenario}', {args.duration:g} s at {args.rate:g} Hz"
          + (", centroider rate-aided by the true body rate (--gyro)" if args.gyro else ""), flush=True)
    prepare_catalog_and_database()
    frames, codes, counters = _run_demo_nodes(args, out)
    summary = _summarize_demo(frames, args.scenario, codes, counters)
    picture = write_picture(frames, out / "frame.png")
    history = write_run_figure(frames, out / "run.png")
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    write_frames_csv(frames, out / "frames.csv")
    print_demo_summary(summary, codes)
    print(f"wrote {picture or '(no identified frame with an image: no picture)'}, {history or '(no run plot)'}, "
          f"{out / 'summary.json'}, {out / 'frames.csv'}")
    healthy = all(code == 0 for code in codes.values()) and summary["frames"] > 0 and picture is not None
    return 0 if healthy else 1


def _run_demo_nodes(args: argparse.Namespace, out: Path):
    """
    Run the nodes (and the recorder with --record) on a private DDS domain.

    Until every frame was reported or the time is up. Returns the monitor's frames in stamp order and the
    processes' exit codes.
    """
    from .ros.pipeline import NodeProcesses, TrackerMonitor, isolated_ros_environment

    env = isolated_ros_environment()
    os.environ.update({k: env[k]
                       for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE")
                       if k in env})
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    frames_wanted = int(round(args.duration * args.rate))
    params = {"camera_simulator": {**SCENARIOS[args.scenario], "rate_hz": float(args.rate),
                                   "max_frames": frames_wanted, "start_delay_s": 2.0, "wait_for_subscribers": True}}
    import rclpy

    rclpy.init(args=[])
    monitor = TrackerMonitor(name="star_tracker_demo_monitor")
    # --gyro: the centroider gets the true body rate, as from a gyro, and uses its rate aid.
    remaps = {"centroider": {"angular_velocity": "truth/angular_velocity"}} if args.gyro else None
    nodes = NodeProcesses(env, out / "logs", params, default_params_file(), remaps=remaps)
    recorder = start_recorder(args.record, env) if args.record else None
    try:
        nodes.start()
        nodes.wait_ready()
        print(f"nodes running (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, logs in {out / 'logs'})", flush=True)
        _print_frame_status(monitor, args.duration, frames_wanted)
        counters = _final_counters(monitor)
    finally:
        codes = nodes.stop()
        if recorder is not None:
            codes["recorder"] = stop_recorder(recorder)
        frames = [monitor.frames[ns] for ns in sorted(monitor.frames)]
        monitor.destroy_node()
        rclpy.try_shutdown()
    return frames, codes, counters


NODES = ("camera_simulator", "centroider", "identifier")


def _final_counters(monitor, timeout_s: float = 3.0) -> dict[str, dict[str, int]]:
    """
    Each node's frame counters from /diagnostics once they cover every frame seen.

    The nodes publish /diagnostics at 1 Hz: wait (up to timeout_s) until each node's counters
    cover every frame the monitor saw, so they explain every frame without an attitude
    (bridged during a lost-in-space solve, dropped to overload, ...).
    """
    from .ros.diagnostics import counters_of

    with_truth = sum(1 for f in monitor.frames.values() if f.truth is not None)

    def counted(node: str, key: str) -> int:
        return int(monitor.diagnostics.get(f"star_tracker/{node}", {}).get(key, "0"))

    def every_frame_counted() -> bool:  # each node has counted what the one before it sent
        return (counted("camera_simulator", "frames_published") >= with_truth
                and counted("centroider", "frames_received") >= counted("camera_simulator", "frames_published")
                and counted("identifier", "frames_received") >= counted("centroider", "frames_processed"))

    monitor.spin_for(timeout_s, until=every_frame_counted)
    return {node: counters_of(monitor.diagnostics.get(f"star_tracker/{node}", {})) for node in NODES}


def _print_frame_status(monitor, duration_s: float, frames_wanted: int) -> None:
    """
    Spin the monitor and print one line per frame.

    Each line as soon as its frame's attitude and matches arrived (or 1.5 s after the frame was
    first seen), until frames_wanted lines or duration_s + 8 s.
    """
    printed: set[int] = set()
    index = 0
    print(f"{'frame':>5}  {'stamp [s]':>16}  {'spots':>5}  {'ident':>5}  {'cross-bore':>10}  {'roll':>8}  "
          f"{'latency':>8}")
    started_frames = time.monotonic()
    end = started_frames + duration_s + 8.0
    while time.monotonic() < end:
        monitor.spin_for(0.2)
        if time.monotonic() > started_frames + duration_s - 2.0:
            monitor.enable_images()  # for the picture: only the last frames are needed
        now = time.monotonic()
        ready = sorted(ns for ns, f in monitor.frames.items() if ns not in printed and f.truth is not None
                       and (f.attitude is not None and f.matched is not None or now - f.first_seen > 1.5))
        for ns in ready:
            printed.add(ns)
            index += 1
            print(_frame_status_line(index, ns, monitor.frames[ns]), flush=True)
        if index >= frames_wanted:
            break


def _frame_status_line(index: int, ns: int, f) -> str:
    """
    Return one status line.

    Frame number, stamp [s], spots, identified stars, attitude error vs truth [arcsec] and
    latency [ms].
    """
    error = f.error()
    spots = "-" if f.spot_count is None else str(f.spot_count)
    if error is None:
        return f"{index:5d}  {ns * 1e-9:16.3f}  {spots:>5}  {'-':>5}  {'not identified':>19}"
    arcsec = np.degrees(error) * 3600
    n_matched = 0 if f.matched is None else f.matched.size
    return (f"{index:5d}  {ns * 1e-9:16.3f}  {spots:>5}  {n_matched:5d}  {arcsec[0]:9.2f}\"  {arcsec[1]:7.2f}\"  "
            f"{f.attitude_latency_s * 1e3:6.0f}ms")


# Identifier counters of frames it received but could not judge: spots that arrived during a
# lost-in-space solve (only the newest of them is published when the solve ends: delay
# compensation), dropped to overload, before any camera_info, or refused by their stamp.
UNJUDGED = ("frames_bridged", "frames_dropped_overload", "frames_without_camera_info", "frames_rejected",
            "frames_unstamped", "frames_from_future", "frames_out_of_order")


def _summarize_demo(frames, scenario: str, codes: dict[str, int], counters: dict[str, dict[str, int]]) -> dict:
    """
    Return the pipeline summary (ros/pipeline.summarize) with the nodes' counters.

    `judged` counts the frames the identifier had the chance to identify: the spots it received
    less those it did not judge (UNJUDGED); `identified_of_judged` is the tracker's rate on them,
    which does not depend on the host's pace. `lost_between_nodes`: frames one node sent and the
    next never received (best-effort image and spots topics on a stalled host).
    """
    from .ros.pipeline import summarize

    summary = summarize(frames)
    camera, centroider = counters.get("camera_simulator", {}), counters.get("centroider", {})
    identifier = counters.get("identifier", {})
    judged = max(0, identifier.get("frames_received", 0) - sum(identifier.get(key, 0) for key in UNJUDGED))
    summary["judged"] = judged
    summary["identified_of_judged"] = summary["identified"] / judged if judged else 0.0
    summary["lost_between_nodes"] = (
        max(0, camera.get("frames_published", 0) - centroider.get("frames_received", 0))
        + max(0, centroider.get("frames_processed", 0) - identifier.get("frames_received", 0)))
    summary["scenario"] = scenario
    summary["node_exit_codes"] = codes
    summary["counters"] = counters
    return summary


def write_frames_csv(frames, path: Path) -> None:
    """
    Write one CSV row per frame with truth.

    Columns: stamp [ns], spots, matched stars, cross-boresight and roll error [arcsec], latency [ms]
    (empty where not identified).
    """
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["stamp_ns", "spots", "matched", "cross_boresight_arcsec", "roll_arcsec", "latency_ms"])
        for f in frames:
            if f.truth is None:
                continue
            err = f.error()
            writer.writerow([f.stamp_ns, f.spot_count, None if f.matched is None else f.matched.size,
                             None if err is None else round(np.degrees(err[0]) * 3600, 3),
                             None if err is None else round(np.degrees(err[1]) * 3600, 3),
                             None if f.attitude_latency_s is None else round(f.attitude_latency_s * 1e3, 2)])


def print_demo_summary(summary: dict, codes: dict[str, int]) -> None:
    """Identification rate, attitude error, latency and the node exit codes of a demo run."""
    print()
    print(f"summary: {summary['frames']} frames, {summary['identified']} identified "
          f"({100 * summary['identification_rate']:.1f} %), {summary['wrong_over_60_arcsec']} wrong (> 60\")")
    print(f"attitude error vs truth: median {summary['cross_boresight_arcsec_median']:.2f}\" cross-boresight, "
          f"{summary['roll_arcsec_median']:.2f}\" roll; 95th percentile {summary['cross_boresight_arcsec_p95']:.2f}\" "
          f"/ {summary['roll_arcsec_p95']:.2f}\"")
    centroider, identifier = summary["counters"].get("centroider", {}), summary["counters"].get("identifier", {})
    overload = identifier.get("frames_dropped_overload", 0) + centroider.get("frames_dropped_overload", 0)
    print(f"judged by the identifier: {summary['judged']} frames, {100 * summary['identified_of_judged']:.1f} % "
          f"identified; not judged: {identifier.get('frames_bridged', 0)} during lost-in-space solves (only the "
          f"newest is published), {overload} dropped to overload, "
          f"{identifier.get('frames_without_camera_info', 0)} before camera_info, "
          f"{summary['lost_between_nodes']} lost between the nodes")
    print(f"latency (mid-exposure stamp -> attitude received): median {summary['latency_ms_median']:.0f} ms, "
          f"max {summary['latency_ms_max']:.0f} ms")
    print(f"node exit codes: {codes}")


def start_recorder(output: str, env: dict[str, str]):
    """
    `star-tracker record` (default topics) as a separate process on the demo's domain.

    It subscribes as the nodes' publishers appear, well before the camera's first exposure
    (the camera waits for its subscribers, then start_delay_s).
    """
    import subprocess

    if Path(output).exists():
        from .commands.common import error

        error("demo", f"--record {output} exists already")
        sys.exit(2)
    cmd = [sys.executable, "-m", "star_tracker.cli", "record", "--output", str(output)]
    print(f"recording the run to {output} (rosbag2, sqlite3)", flush=True)
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop_recorder(process) -> int:
    """SIGINT (the bag is finished), then print the recorder's per-topic report."""
    import signal
    import subprocess

    process.send_signal(signal.SIGINT)
    try:
        output, _ = process.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        process.kill()
        output, _ = process.communicate()
    print("recorder:\n" + "\n".join("  " + line for line in output.splitlines() if not line.startswith("recording /")),
          flush=True)
    return process.returncode


def write_run_figure(frames, path: Path) -> Path | None:
    """Attitude error and rate against time for the run (visualize.run_figure), or None when no frame had truth."""
    from .visualize import run_arrays, run_figure, save_figure

    arrays = run_arrays(frames)
    if arrays["time_s"].size == 0:
        return None
    save_figure(run_figure(**arrays, title="demo run"), path)
    return path


def write_picture(frames, path: Path) -> Path | None:
    """Draw the newest identified frame: its image, identified stars circled + HIP labels."""
    import cv2

    from .visualize import annotate_frame

    for f in reversed(frames):
        if f.image is not None and f.matched is not None and f.matched.size:
            err = f.error()
            title = (f"{f.matched.size} stars identified" +
                     (f", error {np.degrees(err[0]) * 3600:.1f}\" cross-boresight / "
                      f"{np.degrees(err[1]) * 3600:.1f}\" roll"
                      if err is not None else ""))
            canvas = annotate_frame(f.image, f.matched["pixel_x"], f.matched["pixel_y"], f.matched["hip_id"], title)
            cv2.imwrite(str(path), canvas)
            return path
    return None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="star-tracker", description="Simulated spacecraft star tracker (ROS 2).")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the three nodes on a scenario with live status and a picture",
                          description="Start camera_simulator, centroider and identifier as separate processes "
                                      "on a private DDS domain, print one status line per frame (spots, identified "
                                      "stars, attitude error vs truth, latency), then a summary; write "
                                      "OUTPUT/frame.png, run.png (attitude error and rate vs time), summary.json and "
                                      "frames.csv.")
    demo.add_argument("--scenario", choices=sorted([*SCENARIOS, "leo"]), default="default",
                      help="attitude motion: default = 0.5 deg/s cross-boresight + slow roll; rest; fast ~1.5 deg/s; "
                           "slew = 20 deg at up to 2 deg/s from t = 3 s; tumble = torque-free tumble ~1.1 deg/s; "
                           "jitter = 0.1 deg/s + 10\" sinusoidal jitter at 3 Hz; leo = --heads heads on a "
                           "nadir-pointing spacecraft over a 550 km sun-synchronous orbit, fused (a full orbit in "
                           "minutes: --speed, --orbits, --frame-interval; writes summary.json, availability.png, "
                           "fused_error.png, sky.png)")
    demo.add_argument("--duration", type=float, default=30.0, help="seconds of frames to simulate (default 30)")
    demo.add_argument("--rate", type=float, default=10.0, help="frame rate [Hz] (default 10)")
    demo.add_argument("--output", default="demo_output", help="output directory (default demo_output)")
    demo.add_argument("--gyro", action="store_true",
                      help="feed the simulator's true body rate to the centroider's angular_velocity input "
                           "(as a gyro would): streaks are detected with a matched filter and fitted on their "
                           "predicted path")
    demo.add_argument("--heads", type=int, default=2, help="--scenario leo: heads (1-3, default 2)")
    demo.add_argument("--speed", type=float, default=30.0,
                      help="--scenario leo: orbit time per wall time (ROS sim time, default 30)")
    demo.add_argument("--orbits", type=float, default=1.0, help="--scenario leo: orbits to simulate (default 1)")
    demo.add_argument("--frame-interval", type=float, default=3.0,
                      help="--scenario leo: orbit time between a head's frames [s] (default 3)")
    demo.add_argument("--record", metavar="DIR",
                      help="also record the run (camera, truth and output topics) to the rosbag2 bag DIR "
                           "with `star-tracker record`; replay it with `star-tracker play DIR`")
    demo.set_defaults(func=cmd_demo)
    from .commands import add_commands, bags  # star_tracker/commands/

    bags.add_commands(sub)  # record, play, info, reindex
    add_commands(sub)  # render, solve, calibrate, database, monitor, bench
    return parser


def main(argv: list[str] | None = None) -> None:
    from .process_memory import keep_freed_memory

    keep_freed_memory()  # our own process: freed frame buffers are reused, not page-faulted in again
    args = build_parser().parse_args(argv)
    if args.command == "demo":
        bad = [f"--{name.replace('_', '-')} {getattr(args, name):g} must be > 0"
               for name in ("duration", "rate", "speed", "orbits", "frame_interval") if not getattr(args, name) > 0]
        if not 1 <= args.heads <= 3:
            bad.append(f"--heads {args.heads} must be 1 to 3")
        if bad:
            from .commands.common import error

            error("demo", "; ".join(bad))
            sys.exit(2)
    sys.exit(args.func(args))


if __name__ == "__main__":
    main()
