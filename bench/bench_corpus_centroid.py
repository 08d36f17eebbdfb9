# SPDX-License-Identifier: Apache-2.0
"""
Centroiding time on the real corpus, split by stage: where `star-tracker solve IMG` spends its centroiding.

    python -m bench.bench_corpus_centroid [--repeat 7] [--cpu] [--only ID,...] [--corpus DIR]
                                          [--quick] [--output docs/BENCHMARKS.md]

Each image of ../shared/realdata (bench/corpus.py) is read as `solve` reads it and centroided
with `solve`'s own configuration for it (`solve IMG --fov <fov_h_deg>` at its defaults), in-process:
one warm call, then `--repeat` timed calls of extract_spots; the median total, and each stage's
median time per call (STAGES: every call of the stage's function, its own callees included, so
nested stages overlap: the streak residual and the free streak fit are parts of the streak fits).
Wall time by default, as `solve --json` timing_s and the other benchmarks' times are; `--cpu`:
process CPU time instead (every thread counts). Freed memory is kept, as the `star-tracker`
command keeps it (star_tracker/process_memory.py). Beside each image: cedar-solve's whole solve
time from the real-image benchmark's results (bench_realdata.json beside --output), when present.

Writes the "## Real images: centroiding time by stage" section of --output and
bench_corpus_centroid.json beside it.
"""
from __future__ import annotations

import argparse
import functools
import importlib
import json
import shlex
import statistics
import sys
import time
from pathlib import Path

from star_tracker.commands.bench import report_progress

from .corpus import CorpusMissing, find_corpus, manifest_entries
from .machine import machine_info, machine_text, utc_now
from .report import write_section

HEADER = "## Real images: centroiding time by stage"
QUICK_IMAGES = ("ubst_webcam_w1", "gran_vega_05sec")
# (label, module, function) timed around every call; the functions are looked up in the module
# that calls them (which imports them by name).
STAGES = (
    ("detection", "star_tracker.centroid.frame_measurement", "detect"),
    ("candidate measurement", "star_tracker.centroid.frame_measurement", "measure_candidates"),
    ("PSF estimate", "star_tracker.centroid.psf_loop", "estimate_psf"),
    ("point fits", "star_tracker.centroid.frame_fits", "fit_points"),
    ("blend fits", "star_tracker.centroid.frame_fits", "fit_blends"),
    ("streak fits", "star_tracker.centroid.frame_fits", "fit_streak_spots"),
    ("streak residual", "star_tracker.centroid.streak.streak_spots", "streak_residual"),
    ("free streak fit (compiled)", "star_tracker.centroid.streak.streak_spots", "fit_streaks"),
)
NESTED = ("streak residual", "free streak fit (compiled)")  # parts of the streak fits


def time_stages(spent: dict, clock=time.perf_counter) -> None:
    """Wrap every STAGES function so that each call adds its `clock` time [s] to spent[label]."""
    for label, module_name, name in STAGES:
        module = importlib.import_module(module_name)
        inner = getattr(module, name)

        @functools.wraps(inner)
        def timed(*args, _inner=inner, _label=label, **kwargs):
            started = clock()
            try:
                return _inner(*args, **kwargs)
            finally:
                spent[_label] = spent.get(_label, 0.0) + clock() - started

        setattr(module, name, timed)


def measure(corpus: Path, ids: list[str] | None, repeat: int, clock=time.perf_counter) -> list[dict]:
    """Per image: size, spots, the median total [ms] over `repeat` timed runs and each stage's median [ms]."""
    from star_tracker.centroid import extract_spots
    from star_tracker.cli import build_parser
    from star_tracker.commands.images import read_image
    from star_tracker.commands.solve import centroid_config

    spent: dict = {}
    time_stages(spent, clock)
    entries = [e for e in manifest_entries(corpus) if not ids or e["id"] in ids]
    unknown = sorted(set(ids or ()) - {e["id"] for e in entries})
    if unknown:
        raise ValueError(f"unknown image id(s) {', '.join(unknown)}; see {corpus / 'MANIFEST.json'}")
    rows = []
    for index, entry in enumerate(entries):
        image = read_image(corpus / entry["file"])
        config = centroid_config(image.pixels, image.description,
                                 build_parser().parse_args(["solve", "x", "--fov", str(entry["fov_h_deg"])]))
        spots = extract_spots(image.pixels, config)  # warm: kernels and the PSF pilot's first call
        runs, stage_runs = [], []
        for _ in range(repeat):
            spent.clear()
            started = clock()
            extract_spots(image.pixels, config)
            runs.append(clock() - started)
            stage_runs.append(dict(spent))
        rows.append({"id": entry["id"], "width": int(entry["width"]), "height": int(entry["height"]),
                     "spots": len(spots), "total_ms": round(1000.0 * statistics.median(runs), 2),
                     "stages_ms": {label: round(1000.0 * statistics.median(run.get(label, 0.0) for run in stage_runs),
                                                2) for label, _, _ in STAGES}})
        report_progress(index + 1, len(entries), entry["id"])
    return rows


def cedar_times_ms(results_dir: Path | None) -> dict[str, float]:
    """cedar-solve's whole solve time per image it solves [ms], from bench_realdata.json in `results_dir`."""
    path = results_dir / "bench_realdata.json" if results_dir else None
    if path is None or not path.is_file():
        return {}
    data = json.loads(path.read_text())
    return {row["id"]: 1000.0 * row["solvers"]["cedar-solve"]["time_s"] for row in data["images"]
            if row["solvers"].get("cedar-solve", {}).get("solved")}


def render_markdown(results: dict) -> str:
    meta, rows, cedar = results["meta"], results["images"], results.get("cedar_solve_ms", {})
    labels = [label for label, _, _ in STAGES]
    clock = "CPU time (every thread)" if meta.get("clock") == "cpu" else "wall time"
    lines = [HEADER, "",
             f"Command: `{meta['command']}`. Measured {meta['date']} in {meta['elapsed_s']:.0f} s on a shared host. "
             f"Machine: {machine_text(meta)}. Raw results: `docs/bench_corpus_centroid.json`.", "",
             "Each image of `../shared/realdata` centroided in-process with `star-tracker solve IMG --fov "
             f"<fov_h_deg>`'s own configuration for it: one warm call, then {meta['repeat']} timed calls of "
             f"`extract_spots`; {clock}, medians. A stage's time counts every call of its function, its callees "
             "included: the streak residual and the free streak fit (in brackets) are parts of the streak fits; the "
             "other stages run one after another inside the total, and the rest of the total is the pilot "
             "detections, background, hot-pixel cleaning and bookkeeping. The centroiding of a solve that retries "
             "with texture ranked last (gran_IMG_007985) counts twice in `solve`'s own timing, once here. "
             "cedar-solve: its whole `solve_from_image` time on the image from § Real images, where it solves it.",
             "",
             "| image | px | spots | total ms | "
             + " | ".join(f"({label})" if label in NESTED else label for label in labels)
             + " | cedar-solve whole solve ms |",
             "|---|---:|---:|---:|" + "---:|" * len(labels) + "---:|"]
    for row in rows:
        stages = " | ".join(f"{row['stages_ms'][label]:.1f}" for label in labels)
        peer = f"{cedar[row['id']]:.1f}" if row["id"] in cedar else "not solved"
        lines.append(f"| {row['id']} | {row['width']}×{row['height']} | {row['spots']} | {row['total_ms']:.1f} | "
                     f"{stages} | {peer} |")
    both = [row for row in rows if row["id"] in cedar]
    if both:
        faster = sum(row["total_ms"] < cedar[row["id"]] for row in both)
        ratios = sorted(row["total_ms"] / cedar[row["id"]] for row in both)
        lines += ["", f"Our centroiding alone against cedar-solve's whole solve, on the {len(both)} images it solves: "
                  f"shorter on {faster}; ratio median {statistics.median(ratios):.2f}, range "
                  f"{ratios[0]:.2f}-{ratios[-1]:.2f}."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="timed calls per image (default 7)")
    parser.add_argument("--cpu", action="store_true", help="process CPU time instead of wall time")
    parser.add_argument("--only", help="comma-separated image ids of the manifest (default: all)")
    parser.add_argument("--corpus", type=Path, help="corpus folder holding MANIFEST.json")
    parser.add_argument("--quick", action="store_true",
                        help=f"two images ({', '.join(QUICK_IMAGES)}), 2 timed calls each (smoke run)")
    parser.add_argument("--output", type=Path, help=f"write the '{HEADER[3:]}' section of this Markdown file")
    parser.add_argument("--json", type=Path, help="raw results (default: bench_corpus_centroid.json beside --output)")
    parser.add_argument("--from-json", type=Path, metavar="JSON",
                        help="measure nothing: write the section of --output from these saved results")
    args = parser.parse_args(argv)
    if args.from_json:
        text = render_markdown(json.loads(args.from_json.read_text()))
        print(text)
        if args.output:
            write_section(args.output, text)
        return 0
    try:
        corpus = find_corpus(args.corpus)
    except CorpusMissing as exc:
        print(f"bench_corpus_centroid: {exc}", file=sys.stderr)
        return 2
    from star_tracker.process_memory import keep_freed_memory

    keep_freed_memory()
    ids = list(QUICK_IMAGES) if args.quick else (
        [name.strip() for name in args.only.split(",") if name.strip()] if args.only else None)
    repeat = 2 if args.quick else args.repeat
    started, date = time.perf_counter(), utc_now()
    rows = measure(corpus, ids, repeat, time.process_time if args.cpu else time.perf_counter)
    meta = {"command": "python -m bench.bench_corpus_centroid" + "".join(
        f" {shlex.quote(a)}" for a in (argv if argv is not None else sys.argv[1:])), "date": date,
        "elapsed_s": time.perf_counter() - started, "repeat": repeat, "clock": "cpu" if args.cpu else "wall",
        "quick": args.quick, **machine_info()}
    results = {"meta": meta, "images": rows,
               "cedar_solve_ms": cedar_times_ms(args.output.parent if args.output else None)}
    text = render_markdown(results)
    print(text)
    if args.output:
        write_section(args.output, text)
    json_path = args.json or (args.output.parent / "bench_corpus_centroid.json" if args.output else None)
    if json_path:
        json_path.write_text(json.dumps(results, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
