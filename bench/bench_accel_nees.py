# SPDX-License-Identifier: Apache-2.0
"""
The attitude covariance under angular acceleration, in process: per-frame NEES over the tracking campaign's grid.

    python -m bench.bench_accel_nees [--rates 1,2,4] [--accelerations 1,2,4] [--runs 2] [--frames 40]
                                     [--output docs/BENCHMARKS.md]

The `characterize tracking` trial (star_tracker/campaign/presets/tracking.py: the default
chain, an eigen-axis slew across the boresight with a little roll that rests 0.5 s,
accelerates to the case's rate and coasts, 10 Hz, 0.1 s exposures) with the centroider aided
as the nodes aid it: the tracker's last rate and angular acceleration carried to the frame
(RateEstimate.at -> SmearModel with the acceleration). The campaign itself aids with the rate
alone and records per phase only a NEES sum; here every solved frame's NEES against the
truth is kept, so the share above chi^2_3(0.997) = 13.9 is known. Phases as the campaign's:
accelerating (the truth rate changes within the exposure) or steady. Each case's run r uses
the generator seeded (r, 10 rate, 10 acceleration). Writes the "## Covariance under
acceleration" section of --output and the per-frame records in docs/bench_accel_nees.json.
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
from pathlib import Path

import numpy as np

from .machine import cpu_model
from .report import write_section

NEES_997 = 13.93  # scipy.stats.chi2.ppf(0.997, 3)
PERIOD_S = 0.1
ASSUMED_BOUND_DEG_S2 = 2.0  # TrackingConfig.max_angular_acceleration_rad_s2's default


def run(rates, accelerations, runs: int, frames: int, aid_acceleration: bool = True) -> list[dict]:
    from star_tracker.campaign.presets.accuracy import truth_hip
    from star_tracker.campaign.presets.default_chain import MAGNITUDE_LIMIT, default_chain
    from star_tracker.campaign.presets.scoring import score
    from star_tracker.centroid import CentroidConfig, extract_spots
    from star_tracker.centroid.streak.smear import SmearModel
    from star_tracker.models.attitude import quaternion_to_matrix
    from star_tracker.sim.motion import SlewMotion
    from star_tracker.sim.render import StarFieldRenderer
    from star_tracker.track.rate import ACCELERATION_MAX_AGE_S
    from star_tracker.track.tracking import Tracker

    chain = default_chain()
    Tracker(chain.identifier).warm_up(chain.camera)
    renderer = StarFieldRenderer(chain.camera, chain.sensor, chain.catalog, magnitude_limit=MAGNITUDE_LIMIT)
    exposure = chain.sensor.exposure_s
    records = []
    for rate in rates:
        for acceleration in accelerations:
            for r in range(runs):
                rng = np.random.default_rng([r, int(round(rate * 10)), int(round(acceleration * 10))])
                azimuth = rng.uniform(0.0, 2.0 * math.pi)
                axis = np.array([math.cos(azimuth), math.sin(azimuth), rng.uniform(-0.3, 0.3)])
                motion = SlewMotion(quaternion_to_matrix(rng.normal(size=4)), axis, angle_rad=math.radians(360.0),
                                    max_rate_rad_s=math.radians(rate), accel_rad_s2=math.radians(acceleration),
                                    t_start=0.5)
                tracker = Tracker(chain.identifier)
                for k in range(frames):
                    t = 0.05 + PERIOD_S * k
                    stamp_ns = int(round(t * 1e9))
                    frame = renderer.render(motion, t, int(rng.integers(2 ** 31)))
                    smear = None
                    if tracker.rate is not None:
                        omega, alpha = tracker.rate.at(stamp_ns)
                        if stamp_ns - tracker.rate.stamp_ns > ACCELERATION_MAX_AGE_S * 1e9:
                            alpha = None  # stale: as the nodes' centroider (rate_input.motion_for_frame)
                        smear = SmearModel(chain.camera, omega if aid_acceleration else tracker.rate.angular_velocity,
                                           exposure, alpha if aid_acceleration else None)
                    spots = extract_spots(frame.image, CentroidConfig(), smear)
                    result = tracker.process(stamp_ns, spots, chain.camera)
                    ident = result.identification
                    if not ident.solved:
                        continue
                    scored = score(ident, truth_hip(frame.truth, spots, ident), frame.truth.rotation, 60.0)
                    change = (motion.angular_velocity_at(t + 0.5 * exposure)
                              - motion.angular_velocity_at(t - 0.5 * exposure))
                    records.append({"rate_deg_s": rate, "acceleration_deg_s2": acceleration, "run": r, "frame": k,
                                    "phase": "accelerating" if np.linalg.norm(change) > 1e-9 else "steady",
                                    "nees": scored["nees"], "cross_arcsec": scored["cross_arcsec"],
                                    "wrong": bool(scored["wrong_star"] or scored["cross_arcsec"] > 60.0)})
                print(f"{rate:g} deg/s, {acceleration:g} deg/s^2, run {r}: {len(records)} frames so far", flush=True)
    return records


def summarize(records: list[dict]) -> dict:
    out = {}
    groups = {"accelerating": lambda r: r["phase"] == "accelerating", "steady": lambda r: r["phase"] == "steady",
              f"accelerating within the assumed {ASSUMED_BOUND_DEG_S2:g} deg/s^2":
                  lambda r: r["phase"] == "accelerating" and r["acceleration_deg_s2"] <= ASSUMED_BOUND_DEG_S2}
    for a in sorted({r["acceleration_deg_s2"] for r in records}):
        groups[f"accelerating at {a:g} deg/s^2"] = lambda r, a=a: r["phase"] == "accelerating" and \
            r["acceleration_deg_s2"] == a
    for name, keep in groups.items():
        nees = np.array([r["nees"] for r in records if keep(r)])
        out[name] = {"frames": int(nees.size), "nees_mean": float(nees.mean()) if nees.size else None,
                     "above_13_9": int(np.sum(nees > NEES_997)),
                     "share_above_13_9": float(np.mean(nees > NEES_997)) if nees.size else None,
                     "nees_max": float(nees.max()) if nees.size else None}
    out["wrong"] = int(sum(r["wrong"] for r in records))
    return out


def render(data: dict) -> str:
    s = data["summary"]
    rows = []
    for name, p in s.items():
        if name == "wrong":
            continue
        mean = "–" if p["nees_mean"] is None else f"{p['nees_mean']:.2f}"
        share = "–" if p["share_above_13_9"] is None else f"{100 * p['share_above_13_9']:.1f} % ({p['above_13_9']})"
        rows.append(f"| {name} | {p['frames']} | {mean} | {share} | "
                    f"{'–' if p['nees_max'] is None else format(p['nees_max'], '.1f')} |")
    return "\n".join([
        "## Covariance under acceleration",
        "",
        f"Command: `{data['command']}` — {data['date']}, {data['machine']}. Per-frame records: "
        "`docs/bench_accel_nees.json`.",
        "",
        f"The tracking campaign's slews in process (rates {data['rates']} deg/s × accelerations "
        f"{data['accelerations']} deg/s², {data['runs']} runs of {data['frames']} frames each; default chain, 10 Hz, "
        "0.1 s exposures), the centroider aided "
        + ("by the tracker's rate and angular acceleration carried to each frame (as the nodes aid it)"
           if data["aid_acceleration"] else "by the tracker's rate alone (as the campaign aids it)")
        + ". NEES of every solved frame against the truth; a consistent covariance: mean 3, 0.3 % above "
        f"χ²₃(0.997) = 13.9. The tracker assumes |dω/dt| ≤ `max_angular_acceleration_rad_s2` (2 °/s²). "
        f"Wrong frames (a wrong star or > 60″): {s['wrong']}.",
        "",
        "| solved frames | count | NEES mean | above 13.9 | NEES max |",
        "|---|---:|---:|---:|---:|",
        *rows,
    ]) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.strip(), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rates", default="1,2,4", help="coast rates [deg/s]")
    parser.add_argument("--accelerations", default="1,2,4", help="accelerations [deg/s^2]")
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--rate-only-aid", action="store_true",
                        help="aid the centroider with the rate alone, as the tracking campaign does")
    parser.add_argument("--output", type=Path, help="Markdown file to update (docs/BENCHMARKS.md)")
    args = parser.parse_args(argv)
    rates = [float(v) for v in args.rates.split(",")]
    accelerations = [float(v) for v in args.accelerations.split(",")]
    records = run(rates, accelerations, args.runs, args.frames, not args.rate_only_aid)
    arguments = shlex.join(sys.argv[1:] if argv is None else argv)
    data = {"command": ("python -m bench.bench_accel_nees " + arguments).strip(),
            "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "machine": f"{cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
                       f"{platform.platform()}",
            "rates": args.rates, "accelerations": args.accelerations, "runs": args.runs, "frames": args.frames,
            "aid_acceleration": not args.rate_only_aid, "summary": summarize(records), "records": records}
    text = render(data)
    print(text)
    if args.output:
        write_section(args.output, text)
        (args.output.parent / "bench_accel_nees.json").write_text(json.dumps(data, indent=1) + "\n")


if __name__ == "__main__":
    main()
