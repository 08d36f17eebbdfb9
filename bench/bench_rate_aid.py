# SPDX-License-Identifier: Apache-2.0
"""
Rate-aid check of the centroider: false alarms with the right rate, detection of a wrong one.

    python -m bench.bench_rate_aid [--frames 8] [--output docs/BENCHMARKS.md]

Default camera (1024 x 1024, 15 deg), SensorModel() defaults (0.1 s exposure), Hipparcos to
Hp 7.5, random attitudes (fixed seed). For each motion (cross-boresight, roll about the
boresight, a random axis) and rate, `--frames` frames are rendered under that constant rate and
measured by extract_spots with the rate aid set to the true rate times 1.0, 0.85, 0.8 and 0.7:
the share of frames whose aid the check rejected (Spots.rate_aid_rejected; rules in
star_tracker/centroid/streak/rate_aid.py, AID_*), and the time of the check itself.
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import time
from pathlib import Path

import numpy as np

import star_tracker.centroid.frame_measurement as measurement_module
from star_tracker.models.camera import CameraModel
from star_tracker.models.catalog import load_hipparcos
from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid.streak.smear import SmearModel
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import StarFieldRenderer
from star_tracker.sim.sensor import SensorModel
from .machine import cpu_model
from .report import write_section
from .scenes import random_rotation

SECTION = "## Rate-aid check"
RATES_DEG_S = (0.3, 1.0, 2.0, 3.0, 5.0)
SCALES = (1.0, 0.85, 0.8, 0.7)


def run(frames: int) -> tuple[dict, list[float]]:
    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0))
    renderer = StarFieldRenderer(camera, SensorModel(), load_hipparcos().at_epoch(2026.0), magnitude_limit=7.5)
    rng = np.random.default_rng(11)
    check = measurement_module.rate_aid_disagrees
    spent: list[float] = []

    def timed(*args):
        t0 = time.perf_counter()
        verdict = check(*args)
        spent.append(time.perf_counter() - t0)
        return verdict

    measurement_module.rate_aid_disagrees = timed
    rejected = {}
    try:
        for kind in ("cross-boresight", "roll", "random axis"):
            for rate in RATES_DEG_S:
                counts = dict.fromkeys(SCALES, 0)
                for k in range(frames):
                    axis = {"cross-boresight": np.array([*rng.normal(size=2), 0.0]), "roll": np.array([0.0, 0.0, 1.0]),
                            "random axis": rng.normal(size=3)}[kind]
                    omega = np.radians(rate) * axis / np.linalg.norm(axis)
                    frame = renderer.render(ConstantRateMotion(random_rotation(rng), omega), 0.0, 1000 + k)
                    for scale in SCALES:
                        spots = extract_spots(frame.image, CentroidConfig(), SmearModel(camera, omega * scale, 0.1))
                        counts[scale] += int(spots.rate_aid_rejected)
                rejected[(kind, rate)] = counts
                print(kind, rate, counts, flush=True)
    finally:
        measurement_module.rate_aid_disagrees = check
    return rejected, spent


def render(rejected: dict, spent: list[float], frames: int, seconds: float) -> str:
    now = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [SECTION, "",
             f"Command: `python -m bench.bench_rate_aid --frames {frames} --output docs/BENCHMARKS.md`. Measured {now} "
             f"in {seconds:.0f} s. Machine: {cpu_model()}, `nproc` = {os.cpu_count()}; Python "
             f"{platform.python_version()}.", "",
             "Frames rendered under a constant body rate (default camera and sensor, 0.1 s exposure, random "
             f"attitudes), {frames} per row, measured with the rate aid set to the true rate times the factor in "
             "each column: frames whose aid the centroider rejected (measured without it). Column 1.0 is the false-"
             "alarm count.", "",
             "| motion | rate [deg/s] | " + " | ".join(f"aid x {s:g}" for s in SCALES) + " |",
             "|---|---:|" + "---:|" * len(SCALES)]
    for (kind, rate), counts in rejected.items():
        lines.append(f"| {kind} | {rate:g} | " + " | ".join(f"{counts[s]} / {frames}" for s in SCALES) + " |")
    false_alarms = sum(c[1.0] for c in rejected.values())
    lines += ["", f"- False alarms (right rate rejected): {false_alarms} of {frames * len(rejected)} frames.",
              f"- Time of the check: median {1e3 * np.median(spent):.2f} ms, max {1e3 * np.max(spent):.2f} ms over "
              f"{len(spent)} aided extractions.",
              "- Roll: arcs near the boresight are short, so a wrong roll rate changes few footprints beyond the "
              "tolerance (1 px or 15 %)."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.strip(), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=8, help="frames per motion and rate")
    parser.add_argument("--output", type=Path, help="Markdown file whose '## Rate-aid check' section is rewritten")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    rejected, spent = run(args.frames)
    text = render(rejected, spent, args.frames, time.perf_counter() - started)
    print(text)
    if args.output:
        write_section(args.output, text)


if __name__ == "__main__":
    main()
