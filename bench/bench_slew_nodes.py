# SPDX-License-Identifier: Apache-2.0
"""
A slew through the three nodes over DDS: the published attitude covariance under angular acceleration.

    python -m bench.bench_slew_nodes [--angle 40] [--rate 2] [--accel 1] [--hz 5] [--runs 1]
                                     [--output docs/BENCHMARKS.md]

camera_simulator -> centroider -> identifier as separate processes with the shipped
config/star_tracker.yaml (the centroider aided by the identifier's own rate and angular
acceleration, as shipped); the
camera runs the `slew` profile: at rest for `--start` s, then an eigen-axis slew of `--angle`
degrees about a cross-boresight axis with a little roll, accelerating at `--accel` deg/s^2 to
`--rate` deg/s, coasting and braking at the same acceleration, `--hz` frames per second of
0.1 s exposures (5 by default, as the node tests: at 10 Hz a loaded two-core host drops
frames to overload, and the gaps, not the covariance, decide the figures). `--runs` repeats
the slew with fresh node processes, run r with the camera's noise seed r, and pools the
frames (one slew has ~20 accelerating frames at 5 Hz: too few to judge a 1 % tail). Each
`attitude_with_covariance` is joined with `truth/attitude` by stamp
(star_tracker.ros.pipeline.TrackerMonitor); its error e (sensor frame, from the truth) and
NEES = e^T P^-1 e are computed per frame. A consistent 3x3 covariance gives a NEES mean of 3
and exceeds chi^2_3(0.997) = 13.9 on 0.3 % of frames. Frames are split by phase from the
truth: accelerating (the truth rate changes within the exposure: ramps, their first and
last frames included) and steady (at rest, coasting). Only published attitudes are judged;
frames the nodes dropped to overload or published no attitude for are counted. Writes the "## Slew through the nodes"
section of --output and the per-frame records in docs/bench_slew_nodes.json.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import platform
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .machine import cpu_model
from .nodes import CONFIG, join_private_ros
from .report import write_section

EXPOSURE_S = 0.1
NEES_997 = 13.93  # chi^2_3 at 0.997 (scipy.stats.chi2.ppf(0.997, 3) = 13.93)
AXIS = [0.6, 0.8, 0.1]  # slew axis, sensor frame (normalised by the simulator): cross-boresight, a little roll


def run(angle_deg: float, rate_deg_s: float, accel_deg_s2: float, hz: float, start_s: float, env: dict,
        seed: int = 0) -> dict:
    """Run the slew (camera noise seed `seed`); return its per-frame records and the nodes' exit codes and counters."""
    import rclpy  # noqa: F401  (initialised by the caller)

    from star_tracker.models.attitude import matrix_to_rotation_vector
    from star_tracker.ros.pipeline import NodeProcesses, TrackerMonitor

    ramp_s = rate_deg_s / accel_deg_s2
    coast_s = max(0.0, (angle_deg - rate_deg_s * ramp_s) / rate_deg_s)
    frames = int(math.ceil((start_s + 2 * ramp_s + coast_s + 2.0) * hz))
    camera = {"max_frames": frames, "start_delay_s": 2.0, "wait_for_subscribers": True, "rate_hz": hz,
              "max_backlog_frames": 8, "sensor.exposure_s": EXPOSURE_S, "attitude.profile": "slew",
              "attitude.slew.axis": AXIS, "attitude.slew.angle_deg": angle_deg,
              "attitude.slew.max_rate_deg_s": rate_deg_s, "attitude.slew.accel_deg_s2": accel_deg_s2,
              "attitude.slew.start_s": start_s, "seed": seed}
    log_dir = Path(tempfile.mkdtemp(prefix="bench_slew_nodes_"))
    monitor = TrackerMonitor(name="bench_slew_monitor")
    nodes = NodeProcesses(env, log_dir, {"camera_simulator": camera}, CONFIG)
    try:
        nodes.start()
        nodes.wait_ready(timeout_s=120)

        def camera_done() -> bool:
            status = monitor.diagnostics.get("star_tracker/camera_simulator", {})
            published = int(status.get("frames_published", "0"))
            return (published + int(status.get("frames_skipped_overrun", "0")) >= frames
                    and sum(f.truth is not None for f in monitor.frames.values()) >= published)
        monitor.spin_for(frames / hz + 60.0, until=camera_done)
        end = time.monotonic() + 60.0
        while time.monotonic() < end:  # drained: no new attitude for 3 s
            before = sum(f.attitude is not None for f in monitor.frames.values())
            monitor.spin_for(3.0)
            if sum(f.attitude is not None for f in monitor.frames.values()) == before:
                break
    finally:
        codes = nodes.stop()
    diagnostics = dict(monitor.diagnostics)
    records = []
    for ns in sorted(monitor.frames):
        f = monitor.frames[ns]
        if f.truth is None:
            continue
        record = {"stamp_ns": ns, "truth_rate_deg_s": None if f.truth_rate is None else
                  float(np.degrees(np.linalg.norm(f.truth_rate)))}
        if f.attitude is not None and f.covariance is not None:
            error = matrix_to_rotation_vector(f.truth.T @ f.attitude)  # sensor frame [rad]
            record.update(error_arcsec=(np.degrees(error) * 3600).tolist(),
                          sigma_arcsec=(np.degrees(np.sqrt(np.diag(f.covariance))) * 3600).tolist(),
                          nees=float(error @ np.linalg.solve(f.covariance, error)))
        records.append(record)
    monitor.destroy_node()
    return {"records": records, "codes": codes, "frames_asked": frames, "log_dir": str(log_dir),
            "counters": {k: v for k, v in diagnostics.items() if k.startswith("star_tracker/")}}


def phases(records: list[dict], rate_deg_s: float, accel_deg_s2: float) -> np.ndarray:
    """
    Return True where a frame's exposure overlaps a ramp (from the truth).

    The slew's start is found from the first moving frame (its truth rate / the acceleration
    before its stamp); the ramps are [s0, s0 + ramp] and, from the last moving frame, the braking one.
    """
    stamps = np.array([r["stamp_ns"] for r in records]) * 1e-9
    rates = np.array([r["truth_rate_deg_s"] if r["truth_rate_deg_s"] is not None else np.nan for r in records])
    ramp = rate_deg_s / accel_deg_s2
    moving = np.flatnonzero(rates > 1e-6)
    if moving.size == 0:
        return np.zeros(stamps.size, bool)
    s0 = stamps[moving[0]] - rates[moving[0]] / accel_deg_s2
    s3 = stamps[moving[-1]] + rates[moving[-1]] / accel_deg_s2  # the end of braking
    half = 0.5 * EXPOSURE_S
    overlaps = lambda a, b: (stamps + half > a) & (stamps - half < b)  # noqa: E731
    return overlaps(s0, s0 + ramp) | overlaps(s3 - ramp, s3)


def summarize(runs: list[dict], rate_deg_s: float, accel_deg_s2: float) -> dict:
    """NEES by phase over the published attitudes of every run (phases from each run's truth)."""
    records = [r for run_data in runs for r in run_data["records"]]
    accelerating = np.concatenate([phases(run_data["records"], rate_deg_s, accel_deg_s2) for run_data in runs]) \
        if records else np.zeros(0, bool)
    out = {"frames": len(records), "published": sum("nees" in r for r in records)}
    for name, mask in (("accelerating", accelerating), ("steady", ~accelerating),
                       ("all", np.ones(len(records), bool))):
        nees = np.array([r["nees"] for r, m in zip(records, mask) if m and "nees" in r])
        out[name] = {"frames": int(mask.sum()), "published": int(nees.size),
                     "nees_mean": float(nees.mean()) if nees.size else None,
                     "nees_median": float(np.median(nees)) if nees.size else None,
                     "above_13_9": int(np.sum(nees > NEES_997)),
                     "share_above_13_9": float(np.mean(nees > NEES_997)) if nees.size else None,
                     "nees_max": float(nees.max()) if nees.size else None}
    return out


def goal_met(summary: dict) -> bool:
    """NEES mean 3 +- 0.3 and <= 1 % above 13.9, in both phases and over all published frames."""
    return all(p["nees_mean"] is not None and abs(p["nees_mean"] - 3.0) <= 0.3 and p["share_above_13_9"] <= 0.01
               for p in (summary["accelerating"], summary["steady"], summary["all"]))


def render(data: dict) -> str:
    s = data["summary"]
    rows = []
    for name in ("accelerating", "steady", "all"):
        p = s[name]
        mean = "–" if p["nees_mean"] is None else f"{p['nees_mean']:.2f}"
        share = "–" if p["share_above_13_9"] is None else f"{100 * p['share_above_13_9']:.1f} % ({p['above_13_9']})"
        rows.append(f"| {name} | {p['frames']} | {p['published']} | {mean} | {share} | "
                    f"{'–' if p['nees_max'] is None else format(p['nees_max'], '.1f')} |")
    met = goal_met(s)
    lines = [
        "## Slew through the nodes",
        "",
        f"Command: `{data['command']}` — {data['date']}, {data['machine']}. Per-frame records: "
        "`docs/bench_slew_nodes.json`.",
        "",
        f"camera_simulator → centroider → identifier as separate processes over DDS (`config/star_tracker.yaml`; "
        f"the centroider aided by the identifier's `angular_velocity` and `angular_acceleration`), a "
        f"**{data['angle_deg']:g}° slew at {data['accel_deg_s2']:g} °/s² to {data['rate_deg_s']:g} °/s** "
        f"(axis {AXIS}, sensor frame), {data['hz']:g} Hz, {EXPOSURE_S * 1e3:g} ms exposures, "
        f"{data['runs']} run{'s' if data['runs'] != 1 else ''} (camera noise seeds 0..{data['runs'] - 1}), "
        f"host load average {data['load']} (1 min, before / after). Each "
        "`attitude_with_covariance` joined with `truth/attitude` by stamp; NEES = eᵀP⁻¹e of its error e. A "
        "consistent covariance: NEES mean 3, 0.3 % of frames above χ²₃(0.997) = 13.9. Accelerating: the exposure "
        "overlaps a ramp (from the truth).",
        "",
        "| phase | frames | published | NEES mean | above 13.9 | NEES max |",
        "|---|---:|---:|---:|---:|---:|",
        *rows,
        "",
        f"Frames without a published attitude: {s['frames'] - s['published']} of {s['frames']}: dropped by "
        f"overload in the centroider {data['dropped']['centroider']}, in the identifier "
        f"{data['dropped']['identifier']}; bridged (delay compensation: only the newest is published) "
        f"{data['dropped']['bridged']}. Exit codes: {data['codes']}. "
        "Goal (NEES mean 3 ± 0.3 and ≤ 1 % above 13.9, accelerating, steady and all): "
        f"**{'met' if met else 'not met'}**.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.strip(), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--angle", type=float, default=40.0, help="slew angle [deg]")
    parser.add_argument("--rate", type=float, default=2.0, help="coast rate [deg/s]")
    parser.add_argument("--accel", type=float, default=1.0, help="acceleration [deg/s^2]")
    parser.add_argument("--hz", type=float, default=5.0, help="camera rate [Hz]")
    parser.add_argument("--start", type=float, default=1.0, help="rest before the slew [s]")
    parser.add_argument("--runs", type=int, default=1, help="slews, each with fresh nodes and camera seed r")
    parser.add_argument("--output", type=Path, help="Markdown file to update (docs/BENCHMARKS.md)")
    parser.add_argument("--render", type=Path, help="write --output's section from this saved bench_slew_nodes.json "
                        "instead of running")
    args = parser.parse_args(argv)
    if args.render:
        data = json.loads(args.render.read_text())
        text = render(data)
        print(text)
        if args.output:
            write_section(args.output, text)
        return

    import rclpy

    join_private_ros()
    load_before = os.getloadavg()[0]
    runs = []
    try:
        for seed in range(args.runs):
            runs.append(run(args.angle, args.rate, args.accel, args.hz, args.start, dict(os.environ), seed))
            print(f"run {seed}: {sum('nees' in r for r in runs[-1]['records'])} attitudes published", flush=True)
    finally:
        rclpy.try_shutdown()
    data = {
        "command": ("python -m bench.bench_slew_nodes " + shlex.join(sys.argv[1:] if argv is None else argv)).strip(),
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": f"{cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.platform()}",
        "load": f"{load_before:.1f} / {os.getloadavg()[0]:.1f}",
        "angle_deg": args.angle, "rate_deg_s": args.rate, "accel_deg_s2": args.accel, "hz": args.hz,
        "runs": args.runs, "codes": [r["codes"] for r in runs], "runs_data": runs,
        "summary": summarize(runs, args.rate, args.accel),
    }
    counter = lambda node, name: sum(int(r["counters"].get(f"star_tracker/{node}", {}).get(name, "0"))  # noqa: E731
                                     for r in runs)
    data["dropped"] = {name: counter(name, "frames_dropped_overload") for name in ("centroider", "identifier")}
    data["dropped"]["bridged"] = counter("identifier", "frames_bridged")
    text = render(data)
    print(text)
    if args.output:
        write_section(args.output, text)
        (args.output.parent / "bench_slew_nodes.json").write_text(json.dumps(data, indent=1, default=str) + "\n")


if __name__ == "__main__":
    main()
