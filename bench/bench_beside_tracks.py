# SPDX-License-Identifier: Apache-2.0
"""
Stars beside a neighbour star or a cosmic-ray track: found, and how well; ours and the peers' centroiders.

    python -m bench.bench_beside_tracks [--frames 40] [--quick] [--no-peers] [--output docs/BENCHMARKS.md]

Frames from bench/alt_renderer.py (not our renderer: its own PSFs and noise), 512², each with
eight pairs of stars 7-16 px apart and eight stars with a 1 px wide track starting 4-5 px from
them (5000 e- per star, SNR ~60; 15000 e- per track, its charge added without shot noise): a
footprint holding two stars, or a star and a track, is long, and each peak in it must be judged
on its own. Per PSF (Gaussian sigma 1 px, a defocused annulus) and centroider (ours at the
centroider's defaults; tetra3rs and cedar-solve at theirs, when installed): the paired and
beside-track stars missed (no spot within 1 px), the RMS error of those found [px] and the false
spots on tracks (no star within 2 px, a track pixel within 2 px). test/centroid/
test_stars_beside_tracks.py asserts on our counts over the same 40 frames.

Writes the "## Stars beside cosmic-ray tracks" section of --output and bench_beside_tracks.json
beside it.
"""
from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from star_tracker.commands.bench import report_progress

from . import alt_renderer as alt
from .machine import machine_info, machine_text, utc_now
from .report import write_section

SIZE = 512
DETECTOR = alt.Detector(sky_e=40.0, read_noise_e=5.0, gain_e_per_adu=1.0)
TRACK_E = 15000.0  # a cosmic ray's charge [e-] along its TRACK_PX pixels
TRACK_PX = 10
PSFS = {"annulus": alt.AnnulusPsf(1.71, 0.85, 0.30), "gaussian": alt.GaussianPsf(1.0)}
HEADER = "## Stars beside cosmic-ray tracks"
FRAMES, QUICK_FRAMES = 40, 8


def scene(psf, seed: int):
    """
    Eight pairs of stars 7-16 px apart and eight stars with a track starting 4-5 px from them, 5000 e- each.

    Returns (image [ADU], star x, y, track pixel x, y, whether each star has a track beside it).
    """
    rng = np.random.default_rng(seed)
    cells = [(64 + 128 * (k % 4), 64 + 128 * (k // 4)) for k in range(16)]
    x, y, beside, track_x, track_y = [], [], [], [], []
    for k, (cx, cy) in enumerate(cells):
        x0, y0 = cx + rng.uniform(-5, 5), cy + rng.uniform(-5, 5)
        angle = rng.uniform(0, np.pi)
        direction = np.array([np.cos(angle), np.sin(angle)])
        if k < 8:  # a pair of stars
            separation = rng.uniform(7.0, 16.0)
            x += [x0, x0 + separation * direction[0]]
            y += [y0, y0 + separation * direction[1]]
            beside += [False, False]
        else:  # a star and a straight track along `direction`, 1 px wide
            x.append(x0)
            y.append(y0)
            beside.append(True)
            start = rng.uniform(4.0, 5.0)
            steps = start + np.arange(TRACK_PX)
            track_x.append(np.rint(x0 + steps * direction[0]).astype(int))
            track_y.append(np.rint(y0 + steps * direction[1]).astype(int))
    frame = alt.render(alt.StarField.build(psf, np.array(x), np.array(y)), 5000.0, DETECTOR, SIZE, SIZE, rng)
    image = frame.image.astype(np.float64)
    for tx, ty in zip(track_x, track_y):
        image[ty, tx] += TRACK_E / TRACK_PX / DETECTOR.gain_e_per_adu
    image = np.clip(image, 0, 65535).astype(np.uint16)
    return image, np.array(x), np.array(y), np.concatenate(track_x), np.concatenate(track_y), np.array(beside)


class Counts(NamedTuple):
    """Over the frames: stars missed (paired, beside a track), errors [px] of those found, spots on tracks."""

    missed_paired: int
    missed_beside: int
    errors: list
    on_tracks: int

    @property
    def rms_px(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.errors))))


def ours(image: np.ndarray) -> np.ndarray:
    """Our centroids at the centroider's defaults, as (N, 2) (x, y) [px]."""
    from star_tracker.centroid import CentroidConfig, extract_spots

    spots = extract_spots(image, CentroidConfig())
    return np.column_stack([spots.x, spots.y])


def count(psf, seeds, centroids: Callable[[np.ndarray], np.ndarray] = ours, times: list | None = None) -> Counts:
    """Centroid every frame of `seeds` (ours by default), count against the truth; each call's time [s] to `times`."""
    missed_paired, missed_beside, errors, on_tracks = 0, 0, [], 0
    for seed in seeds:
        image, x, y, track_x, track_y, beside = scene(psf, seed)
        started = time.perf_counter()
        xy = np.asarray(centroids(image), float).reshape(-1, 2)
        if times is not None:
            times.append(time.perf_counter() - started)
        distance = np.hypot(xy[:, 0, None] - x[None], xy[:, 1, None] - y[None])
        nearest = distance.min(axis=0) if len(xy) else np.full(x.size, np.inf)
        missed_paired += int(np.sum(nearest[~beside] > 1.0))
        missed_beside += int(np.sum(nearest[beside] > 1.0))
        errors += nearest[nearest <= 1.0].tolist()
        if len(xy):
            unmatched = distance.min(axis=1) > 2.0
            to_track = np.hypot(xy[:, 0, None] - track_x[None], xy[:, 1, None] - track_y[None]).min(axis=1)
            on_tracks += int(np.sum(unmatched & (to_track < 2.0)))
    return Counts(missed_paired, missed_beside, errors, on_tracks)


def centroiders(peers: bool) -> dict[str, Callable[[np.ndarray], np.ndarray]]:
    """Return our centroider and, with `peers`, the usable peers' (bench/peers.py), by name."""
    out = {"ours": ours}
    if peers:
        from . import peers as peer_adapters

        functions = {"tetra3rs": peer_adapters.tetra3rs_centroids, "cedar-solve": peer_adapters.cedar_centroids}
        out.update({name: functions[name] for name in peer_adapters.usable_peers()})
    return out


def run(frames: int, peers: bool) -> list[dict]:
    """One row per PSF and centroider: the counts over `frames` frames, and the time per frame."""
    rows = []
    methods = centroiders(peers)
    total, done = len(PSFS) * len(methods), 0
    for psf_name, psf in PSFS.items():
        for name, function in methods.items():
            function(scene(psf, 10_000)[0])  # warm-up: kernels compiled or loaded, not timed
            times: list[float] = []
            counts = count(psf, range(frames), function, times)
            rows.append({"psf": psf_name, "centroider": name, "frames": frames, "paired": 16 * frames,
                         "beside": 8 * frames, "missed_paired": counts.missed_paired,
                         "missed_beside": counts.missed_beside, "found": len(counts.errors),
                         "rms_px": counts.rms_px if counts.errors else None, "on_tracks": counts.on_tracks,
                         "ms_per_frame": 1e3 * float(np.median(times))})
            done += 1
            report_progress(done, total, f"{psf_name} {name}")
    return rows


def _ratio(value, reference) -> str:
    if value is None or reference is None or reference == 0:
        return "–"
    return f"{value / reference:.2f}"


def render_markdown(results: dict) -> str:
    meta, rows = results["meta"], results["rows"]
    frames = rows[0]["frames"] if rows else 0
    lines = [HEADER, "",
             f"Command: `{meta['command']}`. Measured {meta['date']} in {meta['elapsed_s']:.0f} s. Machine: "
             f"{machine_text(meta)}" + (f"; {', '.join(f'{k} {v}' for k, v in meta['versions'].items() if v)}"
                                        if any((meta.get('versions') or {}).values()) else "") + ". Raw results: "
             "`docs/bench_beside_tracks.json`.", "",
             f"Frames from the second renderer (`bench/alt_renderer.py`), 512², {frames} per PSF: each holds eight "
             "pairs of stars 7-16 px apart and eight stars with a 1 px wide cosmic-ray track starting 4-5 px from "
             "them (5000 e⁻ per star, SNR ~60; 15 000 e⁻ per 10 px track), so that one detection footprint holds two "
             "stars, or a star and a track. Ours at the centroider's defaults, the peers' centroiders at theirs. "
             "Time: the centroiding call alone, median over the frames, on a shared host. "
             "Missed: no spot within 1 px of the star; RMS over the stars found; on tracks: spots with no star "
             "within 2 px and a track pixel within 2 px (false detections).", "",
             "| PSF | centroider | paired stars missed | beside a track missed | RMS error px | spots on tracks | "
             "median ms per frame |", "|---|---|---:|---:|---:|---:|---:|"]
    for row in rows:
        rms = "–" if row["rms_px"] is None else f"{row['rms_px']:.3f}"
        lines.append(f"| {row['psf']} | {row['centroider']} | {row['missed_paired']} of {row['paired']} | "
                     f"{row['missed_beside']} of {row['beside']} | {rms} | {row['on_tracks']} | "
                     f"{row['ms_per_frame']:.1f} |")
    ours_rows = {row["psf"]: row for row in rows if row["centroider"] == "ours"}
    peers = [row for row in rows if row["centroider"] != "ours"]
    if peers:
        lines += ["", "Peers against ours (same frames): stars found (of paired and beside-track stars) and RMS error "
                  "as ratios peer / ours:", ""]
        for row in peers:
            mine = ours_rows[row["psf"]]
            lines.append(f"- {row['psf']}, {row['centroider']}: found {row['found']} vs {mine['found']} (ratio "
                         f"{_ratio(row['found'], mine['found'])}); RMS error {_ratio(row['rms_px'], mine['rms_px'])}×; "
                         f"spots on tracks {row['on_tracks']} vs {mine['on_tracks']}; time "
                         f"{_ratio(row['ms_per_frame'], mine['ms_per_frame'])}×.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--frames", type=int, default=FRAMES, help=f"frames per PSF (default {FRAMES})")
    parser.add_argument("--quick", action="store_true", help=f"{QUICK_FRAMES} frames per PSF (smoke run)")
    parser.add_argument("--no-peers", action="store_true", help="our centroider only")
    parser.add_argument("--output", type=Path, help=f"write the '{HEADER[3:]}' section of this Markdown file")
    parser.add_argument("--json", type=Path, help="raw results (default: bench_beside_tracks.json beside --output)")
    parser.add_argument("--from-json", type=Path, metavar="JSON",
                        help="measure nothing: write the section of --output from these saved results")
    args = parser.parse_args(argv)
    if args.from_json:
        text = render_markdown(json.loads(args.from_json.read_text()))
        print(text)
        if args.output:
            write_section(args.output, text)
        return 0
    frames = QUICK_FRAMES if args.quick else args.frames
    started, date = time.perf_counter(), utc_now()
    rows = run(frames, peers=not args.no_peers)
    meta = {"command": "python -m bench.bench_beside_tracks" + "".join(
        f" {shlex.quote(a)}" for a in (argv if argv is not None else sys.argv[1:])), "date": date,
        "elapsed_s": time.perf_counter() - started, "quick": args.quick, **machine_info(peers=True)}
    results = {"meta": meta, "rows": rows}
    text = render_markdown(results)
    print(text)
    if args.output:
        write_section(args.output, text)
    json_path = args.json or (args.output.parent / "bench_beside_tracks.json" if args.output else None)
    if json_path:
        json_path.write_text(json.dumps(results, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
