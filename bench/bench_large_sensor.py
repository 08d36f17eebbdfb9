# SPDX-License-Identifier: Apache-2.0
"""
A larger sensor through the three nodes: 2048² mono16 frames at 10 Hz.

    python -m bench.bench_large_sensor [--size 2048] [--rate 10] [--seconds 30] [--exposure 0.02]
                                       [--output docs/BENCHMARKS.md]

camera_simulator -> centroider -> identifier as separate processes over DDS, exactly as the
pipeline benchmark's rate sweep runs them (bench_pipeline.sweep: `config/star_tracker.yaml`, the
demo body rate, the rate aid, the camera rendering each frame ahead and publishing it when its
exposure ends), with the camera's `image.width` and `image.height` set to --size at the same
15° field (so the same stars, each over twice the pixels, and 8 MiB a frame). Judged against
the camera's truth: frames identified, dropped (and by whom), wrong (> 60″), latency
(attitude received by this benchmark's subscriber - mid-exposure stamp) and CPU per frame.
Goal (issue: larger sensors): every frame identified, median latency <= 100 ms.

Writes the "## Larger sensor through the nodes" section of --output and the raw numbers in
docs/bench_large_sensor.json.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import shlex
import sys
import tempfile
import time
from pathlib import Path

from .bench_pipeline import fmt, sweep
from .machine import cpu_model
from .nodes import join_private_ros
from .report import write_section

LATENCY_GOAL_MS = 100.0
HEADER = "## Larger sensor through the nodes"


def render_section(data: dict) -> str:
    """Return the Markdown section of one run's raw numbers."""
    r = data["result"]
    lat, cpu, st = r["latency_ms"], r["cpu_ms_per_frame"], r["stages_ms"]
    cam, cen, ide = st["camera_simulator"], st["centroider"], st["identifier"]
    met = r["identified"] == r["frames"] and r["frames"] > 0 and lat["median"] <= LATENCY_GOAL_MS
    size = data["size"]
    return "\n".join([
        HEADER,
        "",
        f"Command: `{data['command']}` — {data['date']}, {data['machine']}; {data['duration_s']:.0f} s. "
        "Raw numbers: `docs/bench_large_sensor.json`.",
        "",
        f"camera_simulator → centroider → identifier as separate processes over DDS, as in the rate sweep of "
        f"[Pipeline throughput and overload](#pipeline-throughput-and-overload) (`config/star_tracker.yaml`, the "
        f"demo's body rate, the rate aid, {data['exposure_ms']:g} ms exposure), with a **{size}² mono16** sensor "
        f"(`image.width` = `image.height` = {size}, the same 15° field: {2 * size * size / 2 ** 20:.0f} MiB a "
        f"frame) at **{data['rate_hz']:g} Hz** for {data['seconds']:g} s. Latency = attitude received by the "
        f"benchmark's subscriber − mid-exposure stamp. {data['load_note']}",
        "",
        "| frames | identified | dropped (camera overrun / centroider / identifier overload) | wrong | latency "
        "median / p95 / max | CPU per frame: camera / centroider / identifier | centroider processing (median) | "
        "identifier processing (median) |",
        "|---:|---:|---|---:|---|---|---:|---:|",
        f"| {r['frames']} | {r['identified']} | {r['dropped']} ({r['camera_skipped_overrun']} / "
        f"{r['centroider_dropped_overload']} / {r['identifier_dropped_overload']}) | {r['wrong']} | "
        f"{fmt(lat['median'])} / {fmt(lat['p95'])} / {fmt(lat['max'])} ms | "
        f"{cpu.get('camera_simulator', float('nan')):.1f} / {cpu.get('centroider', float('nan')):.1f} / "
        f"{cpu.get('identifier', float('nan')):.1f} ms | {fmt(cen.get('processing'))} ms | "
        f"{fmt(ide.get('processing'))} ms |",
        "",
        f"Stage medians from `/diagnostics`: camera render {fmt(cam.get('render'))} ms (ahead of delivery), image "
        f"published {fmt(cam.get('image_age'))} ms after the stamp; the centroider received it "
        f"{fmt(cen.get('input_age'))} ms after the stamp; the identifier received the spots "
        f"{fmt(ide.get('input_age'))} ms after the stamp. Host busy {r['host']['busy_percent']:.0f} %, steal "
        f"{r['host']['steal_percent']:.1f} %.",
        "",
        f"Goal (every frame identified, median latency ≤ {LATENCY_GOAL_MS:g} ms): **{'met' if met else 'not met'}**. "
        f"Exit codes (SIGINT): {data['exit_codes']}.",
    ]) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.strip(), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=2048, help="image width and height [px]")
    parser.add_argument("--rate", type=float, default=10.0, help="camera rate [Hz]")
    parser.add_argument("--seconds", type=float, default=30.0, help="measured window [s]")
    parser.add_argument("--exposure", type=float, default=0.02, help="exposure time [s]")
    parser.add_argument("--output", type=Path, help="Markdown file to update (docs/BENCHMARKS.md)")
    parser.add_argument("--render", type=Path, help="only rewrite the section from this raw-numbers JSON")
    args = parser.parse_args(argv)
    if args.render:
        publish(json.loads(args.render.read_text()), args.output)
        return
    started = time.monotonic()

    import rclpy

    env = join_private_ros()
    log_dir = Path(tempfile.mkdtemp(prefix="bench_large_sensor_"))
    try:
        results, codes = sweep(env, log_dir, [args.rate], args.seconds, args.exposure,
                               camera_parameters={"image.width": args.size, "image.height": args.size})
    finally:
        rclpy.try_shutdown()
    load = os.getloadavg()
    data = {
        "command": ("python -m bench.bench_large_sensor " + shlex.join(sys.argv[1:] if argv is None else argv)).strip(),
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": f"{cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.platform()}",
        "duration_s": time.monotonic() - started, "size": args.size, "rate_hz": args.rate, "seconds": args.seconds,
        "exposure_ms": args.exposure * 1e3, "result": results[0], "exit_codes": codes, "log_dir": str(log_dir),
        "load_note": f"Load average at the end: {load[0]:.2f}.",
    }
    publish(data, args.output)


def publish(data: dict, output: Path | None) -> None:
    """Print the section; with `output`, write it there and the raw numbers beside it."""
    section = render_section(data)
    print(section)
    if output:
        write_section(output, section)
        (output.parent / "bench_large_sensor.json").write_text(json.dumps(data, indent=1, default=str) + "\n")


if __name__ == "__main__":
    main()
