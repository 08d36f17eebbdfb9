# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker demo --scenario leo --heads N`: N heads on a spacecraft in orbit, fused; a full orbit in minutes.

The LEO scenario (ros/leo_scenario.py): each head's camera_simulator, centroider and
identifier in namespace head<i>, the attitude_fusion node, all on ROS sim time from a /clock
this command publishes `--speed` times faster than the wall clock (ros/sim_clock.py); the
cameras expose every `--frame-interval` seconds of orbit time (each exposure still smeared at
the true body rate). It prints a line a minute of orbit time, then availability per head and
fused, and writes OUTPUT/summary.json (a section per head and a `fused` one: frames,
available, wrong (> 60" from the truth), the error's RMS and mean, the blinded/occulted intervals
of each head and the fused attitude's unavailable ones), frames.csv (a row per frame and per
fusion: status and error per axis), availability.png
(per head: tracking / blinded by the Sun, the Earth or the Moon / occulted; fused),
fused_error.png (the fused error per body axis against time) and sky.png (the heads'
boresights over the orbit with the Sun's and the Moon's exclusion cones), and the node logs.
"""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import numpy as np

WRONG_RAD = math.radians(60.0 / 3600.0)
ORBIT_PERIOD_550_KM_S = 5739.0  # a 550 km circular orbit's period [s]
BLOCKED = ("occulted", "blinded_sun", "blinded_earth", "blinded_moon")


def run_orbit_demo(args) -> int:
    """Run the scenario (module docstring); exit code 0 when every node exited cleanly and the heads' frames came."""
    from ..ros import leo_scenario

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    heads = leo_scenario.head_names(args.heads)
    orbit_s = args.orbits * ORBIT_PERIOD_550_KM_S
    print(f"star_tracker demo: scenario 'leo', {len(heads)} heads, {orbit_s:.0f} s of orbit time at {args.speed:g}x "
          f"(~{orbit_s / args.speed / 60:.1f} min), a frame every {args.frame_interval:g} s of orbit time", flush=True)
    frames, fused, codes, start_s = _run_nodes(args, heads, out, orbit_s)
    summary = summarize(frames, fused, heads, args.frame_interval)
    summary.update(scenario="leo", heads=heads, orbit_time_s=orbit_s, speed=args.speed, start_unix_s=start_s,
                   node_exit_codes=codes)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    write_frames_csv(frames, fused, heads, out / "frames.csv")
    from ..visualize_orbit import availability_figure, fused_error_figure, sky_figure

    pictures = [availability_figure(frames, fused, heads, start_s, out / "availability.png"),
                fused_error_figure(fused, start_s, out / "fused_error.png"),
                sky_figure(frames, heads, start_s, start_s + orbit_s, out / "sky.png")]
    print_summary(summary)
    print("wrote " + ", ".join(str(p) for p in [out / "summary.json", out / "frames.csv", *pictures]
                               if p is not None))
    healthy = all(code == 0 for code in codes.values()) and all(summary[h]["frames"] > 0 for h in heads)
    return 0 if healthy else 1


def _node_sets(args, heads, out: Path, env, epoch: str):
    """Return each head's NodeProcesses (namespace head<i>) and the fusion's, all on sim time."""
    from .demo_setup import default_params_file
    from ..ros import leo_scenario
    from ..ros.pipeline import NodeProcesses

    frames = int(round(args.orbits * ORBIT_PERIOD_550_KM_S / args.frame_interval))
    sets = {}
    for index, head in enumerate(heads):
        camera = {**leo_scenario.camera_parameters(head, index, 1.0 / args.frame_interval, epoch),
                  "max_frames": frames, "start_delay_s": 2.0 * args.speed, "wait_for_subscribers": True}
        params = {name: {"use_sim_time": True} for name in ("camera_simulator", "centroider", "identifier")}
        params["camera_simulator"].update(camera)
        params["centroider"].update(leo_scenario.CENTROIDER)
        params["identifier"].update(leo_scenario.IDENTIFIER)
        remaps = {name: {"__ns": f"/{head}", **leo_scenario.REMAPS.get(name, {})}
                  for name in ("camera_simulator", "centroider", "identifier")}
        sets[head] = NodeProcesses(env, out / "logs" / head, params, default_params_file(), remaps=remaps)
    fusion = {"attitude_fusion": {**leo_scenario.fusion_parameters(heads), "use_sim_time": True}}
    sets["fusion"] = NodeProcesses(env, out / "logs", fusion, default_params_file(), nodes=("attitude_fusion",),
                                   remaps={"attitude_fusion": leo_scenario.REMAPS["attitude_fusion"]})
    return sets


def _run_nodes(args, heads, out: Path, orbit_s: float):
    """Start the clock and the nodes, monitor until the orbit is covered; return (frames, fused, exit codes, start)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from .demo_setup import prepare_catalog_and_database
    from ..models.ephemeris import load_ephemeris
    from ..ros import leo_scenario
    from ..ros.pipeline import isolated_ros_environment
    from ..ros.sim_clock import SimClock
    from .orbit_monitor import OrbitMonitor

    prepare_catalog_and_database()
    load_ephemeris()
    env = isolated_ros_environment()
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE",
                                           "FASTRTPS_DEFAULT_PROFILES_FILE") if k in env})
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    rclpy.init(args=[])
    start_s = time.time()
    clock = SimClock(start_s, args.speed)
    monitor = OrbitMonitor(heads)
    executor = SingleThreadedExecutor()
    executor.add_node(clock)
    executor.add_node(monitor)
    sets = _node_sets(args, heads, out, env, leo_scenario.epoch_utc(start_s))
    codes = {}
    try:
        for name, nodes in sets.items():  # the heads' processing first, their cameras waiting for subscribers
            nodes.start()
        for nodes in sets.values():
            nodes.wait_ready()
        print(f"nodes running (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, logs in {out / 'logs'})", flush=True)
        _spin(executor, monitor, clock, orbit_s, args)
    finally:
        for name, nodes in sets.items():
            codes.update({f"{name}/{k}" if name != "fusion" else k: v for k, v in nodes.stop().items()})
        frames, fused = monitor.frames, monitor.fused
        executor.shutdown()
        monitor.destroy_node()
        clock.destroy_node()
        rclpy.try_shutdown()
    return frames, fused, codes, start_s


def _spin(executor, monitor, clock, orbit_s: float, args) -> None:
    """Spin until every head's frames cover orbit_s of orbit time (or the wall time allows no more)."""
    deadline = time.monotonic() + orbit_s / args.speed + 180.0
    next_line = 60.0
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.005)
        covered = monitor.covered_s()
        if covered >= next_line:
            print(monitor.progress_line(covered), flush=True)
            next_line += 60.0 * max(1, round(orbit_s / 60 / 20))
        if covered >= orbit_s - 2 * args.frame_interval:
            break


def intervals(stamps: list[int], statuses: list[str], interval_s: float) -> list[dict]:
    """Return the runs of BLOCKED statuses: [{status, start_s, end_s, frames}] (stamps [ns], sorted)."""
    runs = []
    for stamp, status in zip(stamps, statuses):
        if status not in BLOCKED:
            continue
        t = stamp * 1e-9
        if runs and runs[-1]["status"] == status and t - runs[-1]["end_s"] <= 1.5 * interval_s:
            runs[-1]["end_s"], runs[-1]["frames"] = t, runs[-1]["frames"] + 1
        else:
            runs.append({"status": status, "start_s": t, "end_s": t, "frames": 1})
    return runs


def summarize(frames: dict, fused: dict, heads: list[str], interval_s: float) -> dict:
    """Return summary.json's per-head and fused sections (see the module docstring)."""
    from ..models.attitude import attitude_error, matrix_to_rotation_vector

    summary = {}
    slots = set()
    for head in heads:
        rows = [frames[head][k] for k in sorted(frames[head]) if frames[head][k].get("truth") is not None]
        solved = [r for r in rows if r.get("attitude") is not None]
        errors = [attitude_error(r["attitude"], r["truth"]) for r in solved]
        axes = np.array([matrix_to_rotation_vector(r["truth"].T @ r["attitude"]) for r in solved]).reshape(-1, 3)
        stamps = [k for k in sorted(frames[head]) if frames[head][k].get("status")]
        summary[head] = {"frames": len(rows), "available": len(solved),
                         "wrong": int(sum(e[2] > WRONG_RAD for e in errors)),
                         "cross_boresight_arcsec_rms": _rms([e[0] for e in errors]),
                         "roll_arcsec_rms": _rms([e[1] for e in errors]),
                         "error_arcsec_mean_xyz": _mean_arcsec(axes),
                         "status_counts": _counts([frames[head][k]["status"] for k in stamps]),
                         "blinded_intervals": intervals(stamps, [frames[head][k]["status"] for k in stamps],
                                                        interval_s)}
        slots |= {int(r["stamp_ns"] * 1e-9 // interval_s) for r in rows}
    fused_rows = [fused[k] for k in sorted(fused) if fused[k].get("truth") is not None]
    covered = {int(r["stamp_ns"] * 1e-9 // interval_s) for r in fused_rows}
    axes = np.array([r["axis_error"] for r in fused_rows]) if fused_rows else np.zeros((0, 3))
    # Per fusion: how many heads had an attitude of that stamp (the fused error differs: one head's
    # roll axis lies 45 deg from body y and z).
    solved_heads = np.array([sum(frames[h].get(r["stamp_ns"], {}).get("attitude") is not None for h in heads)
                             for r in fused_rows], dtype=int)
    by_heads = {str(n): {"fusions": int(np.count_nonzero(solved_heads == n)),
                         "error_arcsec_rms_xyz": [_rms(axes[solved_heads == n, k]) for k in range(3)]}
                for n in sorted(set(solved_heads.tolist()))}
    summary["fused"] = {"frames": len(slots), "available": len(slots & covered), "fusions": len(fused_rows),
                        "wrong": int(sum(np.linalg.norm(a) > WRONG_RAD for a in axes)),
                        "error_arcsec_rms_xyz": [_rms(axes[:, k]) for k in range(3)] if len(axes) else None,
                        "error_arcsec_mean_xyz": _mean_arcsec(axes),
                        "by_heads_with_attitude": by_heads,
                        "unavailable_intervals": _gaps(sorted(slots), covered, interval_s)}
    return summary


def write_frames_csv(frames: dict, fused: dict, heads: list[str], path: Path) -> None:
    """
    Write one row per head frame and per fusion: source (head or "fused"), stamp_ns, status, the error [arcsec].

    error_x/y/z: the rotation vector of R_true^T R_estimate, in the head frame for a head (z =
    roll), in the body frame for the fusion; empty without an attitude or a truth.
    """
    import csv

    from ..models.attitude import matrix_to_rotation_vector

    def error(truth, estimate) -> list:
        if truth is None or estimate is None:
            return ["", "", ""]
        return [f"{v:.4f}" for v in np.degrees(matrix_to_rotation_vector(truth.T @ estimate)) * 3600.0]

    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["source", "stamp_ns", "status", "error_x_arcsec", "error_y_arcsec", "error_z_arcsec"])
        for head in heads:
            for stamp in sorted(frames[head]):
                row = frames[head][stamp]
                writer.writerow([head, stamp, row.get("status", ""), *error(row.get("truth"), row.get("attitude"))])
        for stamp in sorted(fused):
            writer.writerow(["fused", stamp, "", *error(fused[stamp]["truth"], fused[stamp]["rotation"])])


def _rms(values) -> float | None:
    values = np.asarray(list(values), float)
    return float(np.degrees(np.sqrt(np.mean(values ** 2))) * 3600.0) if values.size else None


def _mean_arcsec(axes: np.ndarray) -> list[float] | None:
    """Return the mean of (N, 3) rotation-vector errors [rad] per axis, in arcsec (the bias; None if empty)."""
    return [float(v) for v in np.degrees(axes.mean(axis=0)) * 3600.0] if len(axes) else None


def _counts(items) -> dict:
    out = {}
    for item in items:
        out[item] = out.get(item, 0) + 1
    return out


def _gaps(slots: list[int], covered: set[int], interval_s: float) -> list[dict]:
    """Return the runs of frame slots without a fused attitude: [{start_s, end_s, frames}]."""
    runs = []
    for slot in slots:
        if slot in covered:
            continue
        if runs and slot - runs[-1]["last"] == 1:
            runs[-1]["last"], runs[-1]["frames"] = slot, runs[-1]["frames"] + 1
        else:
            runs.append({"first": slot, "last": slot, "frames": 1})
    return [{"start_s": r["first"] * interval_s, "end_s": (r["last"] + 1) * interval_s, "frames": r["frames"]}
            for r in runs]


def print_summary(summary: dict) -> None:
    print()
    for name in [*summary["heads"], "fused"]:
        s = summary[name]
        rate = 100.0 * s["available"] / max(s["frames"], 1)
        line = f"{name:>6}: {s['available']}/{s['frames']} frames with an attitude ({rate:.1f} %), {s['wrong']} wrong"
        if name != "fused":
            line += f"; statuses {s['status_counts']}"
        elif s["error_arcsec_rms_xyz"]:
            line += f"; error RMS per body axis {', '.join(f'{v:.2f}' for v in s['error_arcsec_rms_xyz'])}\""
        print(line)
        if name == "fused":
            for count, part in s["by_heads_with_attitude"].items():
                print(f"        {part['fusions']} fusions with {count} head(s) solved: error RMS per body axis "
                      + ", ".join(f"{v:.2f}" for v in part["error_arcsec_rms_xyz"]) + '"')
    print(f"node exit codes: {summary['node_exit_codes']}")
