# SPDX-License-Identifier: Apache-2.0
"""
Centroiding CPU time per real-corpus image, in-process: what `star-tracker solve IMG` spends in extract_spots.

    python -m bench.corpus_centroid_time [--corpus DIR] [--repeat 7] [--stages] [--wall] [IMAGE_ID ...]

Prints JSON {image id: median CPU time [ms]} over `--repeat` runs after a warm one (CPU
time: the VM's steal does not count; compare runs made in alternation; it counts every thread,
so a multithreaded BLAS call on a crowded frame counts up to twice on 2 cores). `--wall`: wall
time instead, as `solve --json` `timing_s` and the benchmarks' times are. Freed memory is kept,
as the `star-tracker` command keeps it (star_tracker/process_memory.py). `--stages`: {image id:
{"total": ms, "stages": {stage: ms}}}, each stage's CPU time per run (every call, its own
callees included, so nested stages overlap: the free streak fit is part of the streak fits).
For an A/B against another commit, run it with PYTHONPATH at a worktree of that commit, in
alternation:

    (cd ../wt && PYTHONPATH=. python /path/to/repo/bench/corpus_centroid_time.py --corpus ../shared/realdata)
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

# --stages: (label, module, function) timed around every call; the functions are looked up in
# the module that calls them (extract.py imports them by name).
STAGES = (
    ("detection", "star_tracker.centroid.extract", "detect"),
    ("candidate measurement", "star_tracker.centroid.extract", "measure_candidates"),
    ("PSF estimate", "star_tracker.centroid.extract", "estimate_psf"),
    ("point fits", "star_tracker.centroid.extract", "fit_points"),
    ("blend fits", "star_tracker.centroid.extract", "fit_blends"),
    ("streak fits", "star_tracker.centroid.extract", "fit_streak_spots"),
    ("streak residual", "star_tracker.centroid.streak.streak_spots", "streak_residual"),
    ("free streak fit (compiled)", "star_tracker.centroid.streak.streak_spots", "fit_streaks"),
)


def time_stages(spent: dict, clock=time.process_time) -> None:
    """Wrap every STAGES function so that each call adds its `clock` time [s] to spent[label]."""
    import functools
    import importlib

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


def main(argv: list[str]) -> None:
    from bench.bench_realdata import find_corpus
    from star_tracker.centroid import extract_spots
    from star_tracker.cli import build_parser
    from star_tracker.commands.images import read_image
    from star_tracker.commands.solve import centroid_config

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument("ids", nargs="*", help="image ids of MANIFEST.json (default: all)")
    parser.add_argument("--corpus", type=Path, default=None)
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--stages", action="store_true", help="also time the centroider's stages (STAGES)")
    parser.add_argument("--wall", action="store_true", help="wall time instead of CPU time")
    args = parser.parse_args(argv)
    clock = time.perf_counter if args.wall else time.process_time
    from star_tracker.process_memory import keep_freed_memory

    keep_freed_memory()
    spent: dict = {}
    if args.stages:
        time_stages(spent, clock)
    corpus = find_corpus(args.corpus)
    manifest = json.loads((corpus / "MANIFEST.json").read_text())["images"]
    chosen = [image for image in manifest if not args.ids or image["id"] in args.ids]
    times = {}
    for entry in chosen:
        image = read_image(corpus / entry["file"])
        config = centroid_config(image.pixels, image.description,
                                 build_parser().parse_args(["solve", "x", "--fov", str(entry["fov_h_deg"])]))
        extract_spots(image.pixels, config)
        runs, stage_runs = [], []
        for _ in range(args.repeat):
            spent.clear()
            started = clock()
            extract_spots(image.pixels, config)
            runs.append(clock() - started)
            stage_runs.append(dict(spent))
        total = round(1000.0 * statistics.median(runs), 2)
        stages = {label: round(1000.0 * statistics.median(run.get(label, 0.0) for run in stage_runs), 2)
                  for label, _, _ in STAGES}
        times[entry["id"]] = {"total": total, "stages": stages} if args.stages else total
    print(json.dumps(times))


if __name__ == "__main__":
    main(sys.argv[1:])
