# SPDX-License-Identifier: Apache-2.0
"""
Soak: the three nodes at full rate for a long run; memory growth and latency drift.

    python -m bench.bench_soak [--minutes 10] [--rate 20] [--exposure 0.02] [--output docs/BENCHMARKS.md]

camera_simulator -> centroider -> identifier as separate processes (config/star_tracker.yaml,
the demo body rate (0.3, 0.4, 0.05) deg/s, `--exposure` for camera and rate aid), `--rate` Hz
for `--minutes`. Every `--sample` seconds: the resident memory (VmRSS, /proc/<pid>/status) of
each node process, and the frames of the interval: published (truth), identified, dropped,
the latency (mid-exposure stamp -> attitude received here) and the overload counters.

Before the measured run, the centroider and identifier are stopped (SIGSTOP) for
`--rehearse-stall` seconds and resumed: the stall a busy host causes sooner or later, here
rehearsed at once, so that every bounded buffer it fills (the DDS reader histories, 10 images
= 20 MiB and 20 spot clouds, and their payload pools, which Fast DDS keeps) is full before the
baseline is taken. Without it the first stall after the baseline showed up as a one-time step
of ~20 MiB. Memory growth is measured from the end of the first minute (catalog, database,
compiled kernels, DDS buffers and the first allocations all settled) to the end; latency drift is the
change of the per-interval median latency from the first to the last minute, and the slope of a
straight line through all intervals. Writes the "## Soak" section of --output, the figures in
docs/RELIABILITY.md (between its `<!-- bench_soak -->` markers) and the time series in
docs/bench_soak.json.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import shlex
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .nodes import (BODY_RATE_DEG_S, CONFIG, STATUS, Watcher, counter_delta, cpu_seconds, host_cpu, host_usage,
                    join_private_ros, rss_mib)
from .machine import cpu_model
from .report import write_section

BEGIN, END = "<!-- bench_soak -->", "<!-- /bench_soak -->"


def soak(minutes: float, rate: float, exposure_s: float, sample_s: float, stall_s: float = 2.0) -> dict:
    from star_tracker.models.attitude import attitude_error, quaternion_to_matrix
    from star_tracker.ros.pipeline import NodeProcesses

    log_dir = Path(tempfile.mkdtemp(prefix="bench_soak_"))
    params = {"camera_simulator": {"rate_hz": rate, "sensor.exposure_s": exposure_s,
                                   "attitude.body_rate_deg_s": BODY_RATE_DEG_S, "wait_for_subscribers": True,
                                   "max_backlog_frames": 1},  # as bench_pipeline: newest frame wins at the source
              "centroider": {"exposure_time_s": exposure_s, "queue_depth": 1}, "identifier": {"queue_depth": 1}}
    nodes = NodeProcesses(dict(os.environ), log_dir, params, CONFIG)  # queue_depth 1: as bench_pipeline
    watcher = Watcher(with_truth=True)
    samples = []
    try:
        nodes.start()
        nodes.wait_ready()
        watcher.wait(60.0, lambda: len(watcher.attitude_at) > 0)
        pids = {name: proc.pid for name, proc in nodes.processes.items()}
        if stall_s > 0:  # fill the bounded buffers a stall fills (module docstring), then settle
            for name in ("centroider", "identifier"):
                os.kill(pids[name], signal.SIGSTOP)
            time.sleep(stall_s)
            for name in ("centroider", "identifier"):
                os.kill(pids[name], signal.SIGCONT)
            time.sleep(5.0)
        start = time.time_ns()
        end = start + int(minutes * 60e9)
        previous = {name: watcher.counters(name) for name in STATUS}
        cpu_previous = {name: cpu_seconds(pid) for name, pid in pids.items()}
        host_previous = host_cpu()
        t0 = start
        while t0 < end:
            t1 = min(t0 + int(sample_s * 1e9), end)
            time.sleep(max(0.0, (t1 - time.time_ns()) * 1e-9))
            counters = {name: watcher.counters(name) for name in STATUS}
            cpu_now = {name: cpu_seconds(pid) for name, pid in pids.items()}
            host_now = host_cpu()
            rss = {name: rss_mib(pid) for name, pid in pids.items()}
            samples.append({"t0_ns": t0, "t1_ns": t1, "rss_mib": rss, "counters": counters,
                            "cpu_s": {n: cpu_now[n] - cpu_previous[n] for n in pids},
                            "host": host_usage(host_previous, host_now),
                            "overload": {n: counter_delta(previous[n], counters[n], "frames_dropped_overload")
                                         for n in ("centroider", "identifier")},
                            "camera_overrun": counter_delta(previous["camera_simulator"], counters["camera_simulator"],
                                                            "frames_skipped_overrun")})
            previous, cpu_previous, host_previous = counters, cpu_now, host_now
            print(f"{(t1 - start) * 1e-9:6.0f} s  RSS " + ", ".join(f"{k} {v:.1f}" for k, v in rss.items())
                  + f" MiB  overload {samples[-1]['overload']}", flush=True)
            t0 = t1
        time.sleep(3.0)  # the last frames' attitudes
        alive = {name: proc.poll() is None for name, proc in nodes.processes.items()}
    finally:
        codes = nodes.stop()
        watcher.close()
    # Frames per interval, by the end of their exposure.
    with watcher.lock:
        truth, attitude, received = dict(watcher.truth), dict(watcher.attitude), dict(watcher.attitude_at)
    half = exposure_s * 0.5e9
    for s in samples:
        stamps = [ns for ns in truth if s["t0_ns"] <= ns + half < s["t1_ns"]]
        solved = [ns for ns in stamps if ns in attitude]
        latency = np.array([(received[ns] - ns) * 1e-6 for ns in solved])
        errors = np.array([attitude_error(quaternion_to_matrix(attitude[ns]), quaternion_to_matrix(truth[ns]))[2]
                           for ns in solved]) * 180 / np.pi * 3600
        s.update(frames=len(stamps), identified=len(solved), wrong=int(np.sum(errors > 60.0)),
                 latency_ms_median=float(np.median(latency)) if latency.size else float("nan"),
                 latency_ms_p95=float(np.percentile(latency, 95)) if latency.size else float("nan"),
                 latency_ms_max=float(latency.max()) if latency.size else float("nan"))
    return {"samples": samples, "codes": codes, "alive_at_end": alive, "log_dir": str(log_dir)}


def dropped(sample: dict) -> int:
    """Frames dropped in one interval: overload in either node, or camera overruns."""
    return sum(sample["overload"].values()) + sample["camera_overrun"]


def summarize(run: dict, sample_s: float) -> dict:
    samples = run["samples"]
    per_minute = max(1, int(round(60 / sample_s)))
    first, last = samples[:per_minute], samples[-per_minute:]
    growth = {}
    for name in samples[0]["rss_mib"]:
        settled, final = samples[min(per_minute, len(samples)) - 1]["rss_mib"][name], samples[-1]["rss_mib"][name]
        growth[name] = {"start_mib": samples[0]["rss_mib"][name], "after_1_min_mib": settled, "end_mib": final,
                        "growth_percent": 100 * (final - settled) / settled,
                        "max_mib": max(s["rss_mib"][name] for s in samples)}
    minutes = np.array([(s["t1_ns"] - samples[0]["t0_ns"]) * 1e-9 / 60 for s in samples])
    medians = np.array([s["latency_ms_median"] for s in samples])
    ok = np.isfinite(medians)
    slope = float(np.polyfit(minutes[ok], medians[ok], 1)[0]) if ok.sum() >= 2 else float("nan")
    frames = sum(s["frames"] for s in samples)
    return {
        "frames": frames, "identified": sum(s["identified"] for s in samples),
        "wrong": sum(s["wrong"] for s in samples),
        "dropped_overload": {n: sum(s["overload"][n] for s in samples) for n in ("centroider", "identifier")},
        "camera_overrun": sum(s["camera_overrun"] for s in samples),
        "memory": growth,
        "latency_first_minute_ms": float(np.nanmedian([s["latency_ms_median"] for s in first])),
        "latency_last_minute_ms": float(np.nanmedian([s["latency_ms_median"] for s in last])),
        "latency_slope_ms_per_min": slope,
        "latency_p95_max_ms": float(np.nanmax([s["latency_ms_p95"] for s in samples])),
        "intervals": len(samples),
        "intervals_with_drops": sum(1 for s in samples if dropped(s)),
        "steal_percent_with_drops": float(np.mean([s["host"]["steal_percent"] for s in samples if dropped(s)]
                                                  or [np.nan])),
        "steal_percent_without_drops": float(np.mean([s["host"]["steal_percent"] for s in samples if not dropped(s)]
                                                     or [np.nan])),
        "host_busy_percent": float(np.mean([s["host"]["busy_percent"] for s in samples])),
        "host_steal_percent": float(np.mean([s["host"]["steal_percent"] for s in samples])),
    }


def _drop_clusters(s: dict) -> str:
    """Where the drops fell: how many sample intervals had any, and the CPU the hypervisor took then and otherwise."""
    if s["intervals_with_drops"] == 0:
        return f"No interval had a drop (the hypervisor took {s['steal_percent_without_drops']:.1f} % of the CPU)"
    return (f"The drops cluster: {s['intervals_with_drops']} of {s['intervals']} intervals had any, and the "
            f"hypervisor took {s['steal_percent_with_drops']:.1f} % of the CPU during those against "
            f"{s['steal_percent_without_drops']:.1f} % during the others")


def render(data: dict) -> str:
    s = data["summary"]
    mem = s["memory"]
    lines = [
        "## Soak",
        "",
        f"Command: `{data['command']}` — {data['date']}, {data['machine']}. Raw time series: `docs/bench_soak.json`.",
        "",
        f"The three nodes as separate processes (`config/star_tracker.yaml`, demo body rate (0.3, 0.4, 0.05) deg/s, "
        f"1024² mono16, {data['exposure_ms']:g} ms exposure, camera `max_backlog_frames: 1`) at **{data['rate_hz']:g} "
        f"Hz for {data['minutes']:g} min**, sampled every {data['sample_s']:g} s. The host was "
        f"{s['host_busy_percent']:.0f} % busy on average ({s['host_steal_percent']:.1f} % stolen by the "
        f"hypervisor){data['load_note']}. "
        + (f"Before the run the centroider and identifier were stopped for {data['rehearsed_stall_s']:g} s and resumed "
           "(a rehearsed host stall: it fills the bounded DDS reader histories and their payload pools before the "
           "memory baseline; see bench/bench_soak.py)." if data.get("rehearsed_stall_s") else
           "No stall was rehearsed before the run."),
        "",
        f"- frames: {s['frames']} published, {s['identified']} identified "
        f"({100 * s['identified'] / max(s['frames'], 1):.2f} %), {s['wrong']} wrong (> 60″); dropped by overload: "
        f"centroider {s['dropped_overload']['centroider']}, identifier {s['dropped_overload']['identifier']}; camera "
        f"overruns {s['camera_overrun']} (all counted on /diagnostics). " + _drop_clusters(s),
        f"- latency (median per {data['sample_s']:g} s interval): first minute {s['latency_first_minute_ms']:.1f} ms, "
        f"last minute {s['latency_last_minute_ms']:.1f} ms, trend {s['latency_slope_ms_per_min']:+.2f} ms/min; worst "
        f"interval p95 {s['latency_p95_max_ms']:.1f} ms",
        f"- exit codes (SIGINT at the end): {data['codes']}",
        "",
        "| process | RSS at start | after 1 min | at the end | growth after the first minute | max |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, m in mem.items():
        lines.append(f"| {name} | {m['start_mib']:.1f} MiB | {m['after_1_min_mib']:.1f} MiB | {m['end_mib']:.1f} MiB | "
                     f"{m['growth_percent']:+.2f} % | {m['max_mib']:.1f} MiB |")
    goal_memory = all(abs(m["growth_percent"]) < 5 for m in mem.values())
    lines += ["", f"Goal (memory growth < 5 %, no latency drift): memory **{'met' if goal_memory else 'not met'}**; "
              f"latency {s['latency_first_minute_ms']:.1f} → {s['latency_last_minute_ms']:.1f} ms median "
              f"({s['latency_slope_ms_per_min']:+.2f} ms/min)."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.strip(), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=20.0, help="camera rate [Hz]")
    parser.add_argument("--exposure", type=float, default=0.02, help="exposure time [s]")
    parser.add_argument("--sample", type=float, default=10.0, help="sampling interval [s]")
    parser.add_argument("--rehearse-stall", type=float, default=2.0,
                        help="stop the centroider and identifier this long before the run, to fill the buffers a "
                             "host stall fills (0: no rehearsal) [s]")
    parser.add_argument("--load-note", default="", help="a remark on other work on the host during the run")
    parser.add_argument("--output", type=Path, help="Markdown file to update (docs/BENCHMARKS.md)")
    parser.add_argument("--render", type=Path, help="only rewrite the sections from this time-series JSON")
    args = parser.parse_args(argv)
    if args.render:
        data = json.loads(args.render.read_text())
        data["summary"] = summarize(data, data["sample_s"])
        write(data, args.output)
        return

    import rclpy

    join_private_ros()
    try:
        run = soak(args.minutes, args.rate, args.exposure, args.sample, args.rehearse_stall)
    finally:
        rclpy.try_shutdown()
    data = {
        "command": "python -m bench.bench_soak " + shlex.join(sys.argv[1:] if argv is None else argv),
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": f"{cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.platform()}",
        "minutes": args.minutes, "rate_hz": args.rate, "exposure_ms": args.exposure * 1e3, "sample_s": args.sample,
        "rehearsed_stall_s": args.rehearse_stall,
        "load_note": (": " + args.load_note) if args.load_note else "",
        **run, "summary": summarize(run, args.sample),
    }
    data["command"] = data["command"].strip()
    write(data, args.output)


def write(data: dict, output: Path | None) -> None:
    text = render(data)
    print(text)
    if output:
        write_section(output, text)
        (output.parent / "bench_soak.json").write_text(json.dumps(data, indent=1, default=str) + "\n")
        reliability = output.parent / "RELIABILITY.md"
        doc = reliability.read_text() if reliability.is_file() else ""  # none beside a --output elsewhere
        if BEGIN in doc:
            head, rest = doc.split(BEGIN, 1)
            body = "\n".join(text.splitlines()[2:])  # without the section header
            reliability.write_text(head + BEGIN + "\n" + body + END + rest.split(END, 1)[1])


if __name__ == "__main__":
    main()
