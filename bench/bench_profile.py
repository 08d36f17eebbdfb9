# SPDX-License-Identifier: Apache-2.0
"""
Where the time goes, by cProfile: nominal and slewing frames, lost-in-space, a tracking update, real images.

    python -m bench.bench_profile [--repeat 9] [--calls 50] [--image-repeat 5] [--image-calls 5]
                                  [--only NAME,...] [--images ID,ID,ID] [--corpus DIR]
                                  [--quick] [--output docs/BENCHMARKS.md]

Workloads (the default chain of the campaigns, star_tracker/campaign/presets/default_chain.py:
1024 x 1024 px, 15 deg, the simulator's SensorModel, Hipparcos rendered to Hp 7.5, the hybrid
identifier with its budget on the CPU clock; frames seeded from SEED):

- nominal: `extract_spots(image, CentroidConfig())` on a frame at rest;
- slewing: the same on a frame slewing at 1.8 deg/s across the boresight, rate-aided as the
  nodes aid it (`SmearModel(camera, omega, exposure_s)`);
- lost_in_space: the default identifier's `identify(spots, camera)` on the nominal frame's spots;
- lost_in_space_cold: the same with the caches cold: EVICT_BYTES written before each call (untimed),
  as a node's solve follows the image's decoding and centroiding (a solve reads scattered parts of
  the pair index, the catalogs and its scratch: their cache misses are then part of its time);
- tracking: `Tracker.process` per frame at 0.5 deg/s (10 Hz, mid-exposure stamps 0.05 + 0.1 k s),
  after TRACK_LEAD frames of tracking; each frame centroided (untimed) with the tracker's own aid
  (`Tracker.centroider_aid`). Every call is a new frame, so the tracker's state moves on as in flight;
- real_<id>: three images of ../shared/realdata (bench/corpus.py; REAL_IMAGES: a narrow-field
  openstartracker frame, a wide gran_* frame, the lost_* one) through `star-tracker solve IMG --fov
  <fov_h_deg> --json --quiet` run in-process (the CLI's parser and the command's run(): reading the
  file, centroiding, field search, identification, camera refinement). Skipped, with a note, when the
  corpus is absent.

Each workload: one warm call (numba compiles or loads its kernels, databases load), then --repeat
timed calls without the profiler (wall time; their median is the workload's time per call), then
--calls calls under cProfile (enabled around the call only: rendering and, for tracking, the
frame's centroiding stay outside). Real images use --image-repeat and --image-calls. The profile
gives each function's own time (tottime); a compiled numba kernel shows as its own entry (numba
reports its calls to the profiler), so its time counts in the kernel's module. cProfile slows
Python-level calls much more than compiled ones: its per-call total exceeds the unprofiled median
(the ratio is reported), and Python-heavy stages are over-represented in the shares; the "at the
median" column scales each share to the unprofiled median, an estimate only. The solve path's
identification budget runs on the CPU clock, which the profiler also consumes: a profiled solve
that times out is reported (solved counts per workload).

Stages (STAGES; a function's stage is the first rule its file matches; paths relative to the
star_tracker package or to site-packages):

- detection: star_tracker/centroid/detection/*
- PSF estimate and point fits: star_tracker/centroid/psf/*, centroid/psf_loop.py
- streak fits: star_tracker/centroid/streak/*
- track and blend screening: star_tracker/centroid/tracks/*
- centroiding, other: the rest of star_tracker/centroid/ (frame measurement and fits orchestration,
  windows, spot records)
- identification: star_tracker/identify/*
- tracking: star_tracker/track/*
- models: star_tracker/models/* (camera, attitude, catalog, camera calibration)
- image read: star_tracker/commands/images.py (decoding the file: cv2 or astropy)
- solve command: the rest of star_tracker/commands/* (field-search loop, the --json record and output)
- star_tracker, other: any other module of the package
- benchmark harness: bench/* (here: parsing the solve's --json output; not part of `solve`)
- numba dispatch: numba/*, llvmlite/* (type dispatch, compilation, cache loading)
- library: every other site-packages module (numpy, scipy, cv2, astropy, ...) and the C built-ins
  named after one of LIBRARIES (numpy's ufuncs and array methods) or found in cv2 (its functions
  have no module name: cProfile shows "<imread>", listed here as cv2.imread)
- Python: the standard library and the remaining built-ins (len, list.append, ...)

Per stage: its own share of the profile (the functions' own time) and ms per profiled call, and
its share with the library calls it makes (callers_stages: library, Python and numba dispatch time
handed on to the package stage that called it, by cProfile's per-caller own time, up through
library callers), scaled to the unprofiled median: what each of our stages costs, numpy included.

Writes the "## Profiles" section of --output and bench_profile.json beside it (or --json):
per workload the median, the profiled time per call, the stages and the top functions by own
time. --from-json rewrites the section from saved results without measuring.
"""
from __future__ import annotations

import argparse
import cProfile
import functools
import json
import math
import os
import pstats
import shlex
import statistics
import sys
import sysconfig
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from star_tracker.commands.bench import report_progress

from .corpus import CorpusMissing, find_corpus, load_corpus, run_solve_command, solve_argv
from .machine import machine_info, machine_text, utc_now
from .report import write_section

HEADER = "## Profiles"
SEED = 20240611
SLEW_RATE_DEG_S = 1.8
TRACK_RATE_DEG_S = 0.5
PERIOD_S = 0.1
TRACK_LEAD = 5  # frames processed before the measured ones: lost-in-space, then tracking with a rate
TOP = 12  # functions listed per workload
REAL_IMAGES = ("openstartracker_img0", "gran_vega_05sec", "lost_img_7660")
SIMULATED = ("nominal", "slewing", "lost_in_space", "lost_in_space_cold", "tracking")
EVICT_BYTES = 64 << 20  # written before each lost_in_space_cold call: more than any cache of the host
LIBRARIES = ("numpy", "scipy", "cv2", "PIL", "astropy", "pyarrow", "erfa")
OTHER_CENTROID, OTHER_PACKAGE, LIBRARY, PYTHON = ("centroiding, other", "star_tracker, other", "library", "Python")
HARNESS = "benchmark harness"
# (stage, path prefixes): relative to the star_tracker package's parent ("star_tracker/...") or to
# site-packages ("numpy/..."); the first match wins. Unmatched: library when under site-packages, else Python.
STAGES = (
    ("detection", ("star_tracker/centroid/detection/",)),
    ("PSF estimate and point fits", ("star_tracker/centroid/psf/", "star_tracker/centroid/psf_loop.py")),
    ("streak fits", ("star_tracker/centroid/streak/",)),
    ("track and blend screening", ("star_tracker/centroid/tracks/",)),
    (OTHER_CENTROID, ("star_tracker/centroid/",)),
    ("identification", ("star_tracker/identify/",)),
    ("tracking", ("star_tracker/track/",)),
    ("models", ("star_tracker/models/",)),
    ("image read", ("star_tracker/commands/images.py",)),
    ("solve command", ("star_tracker/commands/",)),
    (OTHER_PACKAGE, ("star_tracker/",)),
    (HARNESS, ("bench/",)),
    ("numba dispatch", ("numba/", "llvmlite/")),
)
STAGE_ORDER = tuple(label for label, _ in STAGES) + (LIBRARY, PYTHON)
PASSED_UP = ("numba dispatch", LIBRARY, PYTHON)  # counted again with the package stage calling them
REPO = Path(__file__).resolve().parents[1]
PACKAGE_PARENT = REPO  # where star_tracker/ and bench/ live (the editable install's source tree)
STDLIB = Path(sysconfig.get_paths()["stdlib"]).resolve()


def cv2_function(function: str) -> str | None:
    """Return "cv2.NAME" when a built-in's profile name "<NAME>" is a cv2 function (cv2 functions have no module)."""
    cv2 = sys.modules.get("cv2")
    name = function[1:-1] if function.startswith("<") and function.endswith(">") else ""
    return f"cv2.{name}" if cv2 is not None and name.isidentifier() and callable(getattr(cv2, name, None)) else None


@functools.lru_cache(maxsize=None)
def short_path(filename: str) -> tuple[str, bool]:
    """Return (the path used for grouping and display, whether it lies in site-packages)."""
    normalized = filename.replace(os.sep, "/")
    if "site-packages/" in normalized:
        return normalized.rsplit("site-packages/", 1)[1], True
    for root in (PACKAGE_PARENT, STDLIB):
        try:
            return Path(filename).resolve().relative_to(root).as_posix(), False
        except ValueError:
            pass
    marker = normalized.rfind("/star_tracker/")  # an installed copy outside this tree
    if marker >= 0:
        return normalized[marker + 1:], False
    return normalized, False


def stage_of(filename: str, function: str) -> str:
    """Return the stage (STAGE_ORDER) of a profile entry: its file, or a built-in's name."""
    if filename == "~":  # a C built-in: "<built-in method numpy...>", "<method 'reduce' of 'numpy.ufunc' objects>"
        return LIBRARY if any(name in function for name in LIBRARIES) or cv2_function(function) else PYTHON
    path, site = short_path(filename)
    for label, prefixes in STAGES:
        if path.startswith(prefixes):
            return label
    return LIBRARY if site else PYTHON


def display_name(filename: str, line: int, function: str) -> str:
    if filename == "~":
        return cv2_function(function) or function
    return f"{short_path(filename)[0]}:{line}({function})"


def callers_stages(stats: dict, key, stage: dict, memo: dict, active: set) -> dict[str, float]:
    """
    Return how the own time of profile entry `key` divides among the package's stages that call it.

    A package stage's own entry is its own; a library, Python or numba dispatch entry's time goes
    to its callers in proportion to the time it spent for each (cProfile's per-caller tottime),
    up through library callers until a package function; with no such caller (or in a cycle) it
    stays where it is.
    """
    if key in memo:
        return memo[key]
    if stage[key] not in PASSED_UP:
        memo[key] = {stage[key]: 1.0}
        return memo[key]
    active.add(key)
    callers = {caller: value for caller, value in stats[key][4].items() if caller in stats and caller not in active}
    weights = {caller: value[2] for caller, value in callers.items()}  # (calls, primitive calls, tottime, cumtime)
    if sum(weights.values()) <= 0.0:  # too quick to time: by the number of calls
        weights = {caller: float(value[0]) for caller, value in callers.items()}
    total = sum(weights.values())
    shares: dict[str, float] = {}
    if total > 0.0:
        for caller, weight in weights.items():
            for label, part in callers_stages(stats, caller, stage, memo, active).items():
                shares[label] = shares.get(label, 0.0) + part * weight / total
    active.discard(key)
    memo[key] = shares or {stage[key]: 1.0}
    return memo[key]


def summarize_profile(stats: pstats.Stats, calls: int, median_s: float) -> dict:
    """
    Return the stages and the TOP functions by own time of a profile of `calls` calls.

    Per stage: its share of the profiled own time, ms per profiled call, and with the library,
    Python and numba dispatch time it calls (callers_stages) its share and ms at the unprofiled
    median `median_s` [s].
    """
    raw = {key: value for key, value in stats.stats.items() if "_lsprof.Profiler" not in key[2]}
    stage = {key: stage_of(key[0], key[2]) for key in raw}
    total = sum(value[2] for value in raw.values())
    spent: dict[str, float] = {}
    spent_with_calls: dict[str, float] = {}
    memo: dict = {}
    for key, value in raw.items():
        spent[stage[key]] = spent.get(stage[key], 0.0) + value[2]
        for label, part in callers_stages(raw, key, stage, memo, set()).items():
            spent_with_calls[label] = spent_with_calls.get(label, 0.0) + part * value[2]
    labels = sorted(set(spent) | set(spent_with_calls), key=lambda label: -spent_with_calls.get(label, 0.0))
    stages = [{"stage": label, "share": spent.get(label, 0.0) / total if total else 0.0,
               "ms_per_call": 1000.0 * spent.get(label, 0.0) / calls,
               "share_with_calls": spent_with_calls.get(label, 0.0) / total if total else 0.0,
               "ms_with_calls_at_median": 1000.0 * median_s * spent_with_calls.get(label, 0.0) / total if total
               else 0.0}
              for label in labels]
    top = []
    by_own_time = sorted(raw.items(), key=lambda entry: -entry[1][2])
    for (filename, line, function), (_, ncalls, own, cumulative, _) in by_own_time[:TOP]:
        top.append({"function": display_name(filename, line, function), "stage": stage_of(filename, function),
                    "calls_per_call": ncalls / calls, "own_ms_per_call": 1000.0 * own / calls,
                    "cumulative_ms_per_call": 1000.0 * cumulative / calls, "share": own / total if total else 0.0})
    return {"profiled_ms_per_call": 1000.0 * total / calls, "function_calls": sum(v[1] for v in raw.values()),
            "stages": stages, "top": top}


@dataclass
class Workload:
    """
    name, title, what (one line on the call); prepare() -> the next call to measure.

    prepare() does the untimed work (rendering; for tracking, the frame's centroiding);
    outcome(result) -> a short label counted per call ("solved", "212 spots", "tracking");
    image: a real image (--image-repeat and --image-calls apply).
    """

    name: str
    title: str
    prepare: Callable[[], Callable[[], object]]
    outcome: Callable[[object], str]
    what: str
    image: bool = False


def measure(workload: Workload, repeat: int, calls: int, clock=time.perf_counter) -> dict:
    """Return the workload's record: one warm call, `repeat` timed calls, then `calls` profiled calls."""
    warm = workload.prepare()
    workload.outcome(warm())  # compiles, loads; its outcome is not counted
    timed, outcomes, profiled_outcomes = [], {}, {}
    for _ in range(repeat):
        call = workload.prepare()
        started = clock()
        result = call()
        timed.append(clock() - started)
        label = workload.outcome(result)
        outcomes[label] = outcomes.get(label, 0) + 1
    profiler = cProfile.Profile()
    for _ in range(calls):
        call = workload.prepare()
        profiler.enable()
        result = call()
        profiler.disable()
        label = workload.outcome(result)
        profiled_outcomes[label] = profiled_outcomes.get(label, 0) + 1
    median = statistics.median(timed)
    record = {"name": workload.name, "title": workload.title, "what": workload.what, "repeat": repeat,
              "calls": calls, "median_ms": 1000.0 * median, "timed_ms": [round(1000.0 * t, 3) for t in timed],
              "outcomes": outcomes, "profiled_outcomes": profiled_outcomes}
    record.update(summarize_profile(pstats.Stats(profiler), calls, median))
    return record


def simulated_workloads(only: set[str]) -> list[Workload]:
    """Return the default chain's workloads named in `only`, their frames rendered and their kernels warm."""
    import numpy as np

    from star_tracker.campaign.presets.default_chain import MAGNITUDE_LIMIT, default_chain
    from star_tracker.centroid import CentroidConfig, extract_spots
    from star_tracker.centroid.streak.smear import SmearModel
    from star_tracker.models.attitude import quaternion_to_matrix
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import StarFieldRenderer, frame_seed
    from star_tracker.track.tracking import Tracker

    chain = default_chain()
    camera, exposure = chain.camera, chain.sensor.exposure_s
    renderer = StarFieldRenderer(camera, chain.sensor, chain.catalog, magnitude_limit=MAGNITUDE_LIMIT)
    rng = np.random.default_rng(SEED)
    start = quaternion_to_matrix(rng.normal(size=4))
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    across = np.array([math.cos(azimuth), math.sin(azimuth), 0.0])  # a cross-boresight rate axis
    config = CentroidConfig()
    workloads = []

    def spots_text(spots) -> str:
        return f"{len(spots)} spots"

    def solved_text(identification) -> str:
        return "solved" if identification.solved else identification.status

    nominal_image = renderer.render(ConstantRateMotion(start, np.zeros(3)), 0.05, frame_seed(SEED, 0)).image
    if "nominal" in only:
        workloads.append(Workload("nominal", "Nominal frame (at rest)",
                                  lambda: lambda: extract_spots(nominal_image, config), spots_text,
                                  "extract_spots(image, CentroidConfig()), a 1024² frame at rest"))
    if "slewing" in only:
        omega = math.radians(SLEW_RATE_DEG_S) * across
        slewing_image = renderer.render(ConstantRateMotion(start, omega), 0.05, frame_seed(SEED, 1)).image
        smear = SmearModel(camera, omega, exposure)
        workloads.append(Workload("slewing", f"Slewing frame ({SLEW_RATE_DEG_S:g} °/s)",
                                  lambda: lambda: extract_spots(slewing_image, config, smear), spots_text,
                                  f"extract_spots(image, CentroidConfig(), SmearModel(camera, omega, {exposure:g} s)),"
                                  f" {SLEW_RATE_DEG_S:g} °/s across the boresight"))
    if only & {"lost_in_space", "lost_in_space_cold", "tracking"}:
        Tracker(chain.identifier).warm_up(camera)  # the identifier's and the tracker's kernels
    if only & {"lost_in_space", "lost_in_space_cold"}:
        nominal_spots = extract_spots(nominal_image, config)
        solve = lambda: chain.identifier.identify(nominal_spots, camera)  # noqa: E731
        what = f"hybrid identifier's identify(spots, camera) on the nominal frame's {len(nominal_spots)} spots"
    if "lost_in_space" in only:
        workloads.append(Workload("lost_in_space", "Lost-in-space solve", lambda: solve, solved_text, what))
    if "lost_in_space_cold" in only:
        scratch = np.zeros(EVICT_BYTES // 8)

        def evicted():
            np.add(scratch, 1.0, out=scratch)  # every cache line of EVICT_BYTES written: the solve's data evicted
            return solve

        workloads.append(Workload("lost_in_space_cold", "Lost-in-space solve, caches evicted", evicted, solved_text,
                                  f"{what}, after writing {EVICT_BYTES >> 20} MiB (untimed)"))
    if "tracking" in only:
        tracker = Tracker(chain.identifier)
        motion = ConstantRateMotion(start, math.radians(TRACK_RATE_DEG_S) * across)
        frame_index = [0]

        def next_frame():
            k = frame_index[0]
            frame_index[0] += 1
            t = 0.05 + PERIOD_S * k
            stamp_ns = int(round(t * 1e9))
            image = renderer.render(motion, t, frame_seed(SEED, 100 + k)).image
            spots = extract_spots(image, config, tracker.centroider_aid(stamp_ns, camera, exposure))
            return lambda: tracker.process(stamp_ns, spots, camera)

        for _ in range(TRACK_LEAD):
            next_frame()()
        workloads.append(Workload("tracking", f"Tracking update ({TRACK_RATE_DEG_S:g} °/s)", next_frame,
                                  lambda tracked: tracked.mode if tracked.solved else f"{tracked.mode} (unsolved)",
                                  f"Tracker.process per new frame at {TRACK_RATE_DEG_S:g} °/s, 10 Hz, after "
                                  f"{TRACK_LEAD} frames; each frame centroided (untimed) with "
                                  "Tracker.centroider_aid"))
    return workloads


def image_workloads(corpus: Path, ids: list[str]) -> list[Workload]:
    """Return the real images `ids` as workloads: `star-tracker solve IMG --fov <fov_h_deg> --json --quiet`."""
    workloads = []
    for image in load_corpus(corpus, ids):
        argv = solve_argv(image)

        def outcome(result) -> str:
            code, record, _, _ = result
            return "solved" if code == 0 else f"not solved (exit {code})"

        shown = ["solve", image.path.name] + argv[2:]
        workloads.append(Workload(f"real_{image.id}", f"Real image {image.id} ({image.width}×{image.height})",
                                  lambda argv=argv: lambda: run_solve_command(argv), outcome,
                                  f"`star-tracker {shlex.join(shown)}` in-process", image=True))
    return workloads


def stage_table(record: dict) -> list[str]:
    lines = ["| stage | own share | own ms per call (profiled) | share with the library calls it makes | "
             "≈ ms at the median, with them |", "|---|---:|---:|---:|---:|"]
    for stage in record["stages"]:
        lines.append(f"| {stage['stage']} | {100 * stage['share']:.1f} % | {stage['ms_per_call']:.2f} | "
                     f"{100 * stage['share_with_calls']:.1f} % | {stage['ms_with_calls_at_median']:.2f} |")
    return lines


def top_table(record: dict) -> list[str]:
    lines = ["| function (own time) | stage | calls per workload call | own ms per call | share |",
             "|---|---|---:|---:|---:|"]
    for top in record["top"]:
        name = top["function"].replace("|", "\\|")
        lines.append(f"| `{name}` | {top['stage']} | {top['calls_per_call']:.4g} | {top['own_ms_per_call']:.2f} | "
                     f"{100 * top['share']:.1f} % |")
    return lines


def dominates(record: dict) -> str:
    """Return one sentence: the leading stages (those above 10 %, at least one), with their library calls and own."""
    def leading(key: str) -> str:
        stages = sorted(record["stages"], key=lambda s: -s[key])
        lead = [s for s in stages if s[key] >= 0.10] or stages[:1]
        return ", then ".join(f"{s['stage']} ({100 * s[key]:.0f} %)" for s in lead[:3])

    if not record["stages"]:
        return ""
    text = f"Dominated by {leading('share_with_calls')} counting the library calls each makes; by own time alone, " \
        f"{leading('share')}."
    if record["top"]:
        first = record["top"][0]
        text += f" The largest single function: `{first['function']}` ({100 * first['share']:.0f} %, {first['stage']})."
    return text


def counted(outcomes: dict) -> str:
    return ", ".join(f"{count}× {label}" for label, count in sorted(outcomes.items()))


def plural(count: int, noun: str) -> str:
    return f"{count} {noun}" + ("" if count == 1 else "s")


def render_markdown(results: dict) -> str:
    meta = results["meta"]
    load = meta.get("load_average")
    lines = [HEADER, "",
             f"Command: `{meta['command']}`. Measured {meta['date']} in {meta['elapsed_s']:.0f} s on a shared host"
             + (f" (load average {load[0]:.1f} over 1 min at the start, {load[2]:.1f} over 15 min)" if load else "")
             + f". Machine: {machine_text(meta)}. Raw results: `docs/bench_profile.json`.", "",
             "Where the time goes per stage: each workload warmed once (kernels compiled or loaded), timed without "
             "the profiler (median wall time per call), then run under cProfile. A stage is a group of functions by "
             "module (bench/bench_profile.py: `star_tracker/centroid/detection/*` = detection, `centroid/psf/*` and "
             "`psf_loop.py` = PSF estimate and point fits, `centroid/streak/*` = streak fits, `centroid/tracks/*` = "
             "track and blend screening, the rest of `centroid/` = centroiding, other, `identify/*` = identification, "
             "`track/*` = tracking, `models/*` = models, `commands/images.py` = image read, the rest of `commands/` = "
             "solve command (field search loop, the `--json` record and output), `bench/*` = benchmark harness "
             "(parsing that output), numba's own modules = numba "
             "dispatch, numpy/scipy/cv2/... and their built-ins = library, the standard library and other built-ins = "
             "Python). Own share: of the functions' own (tottime) time. \"With the library calls it makes\": the "
             "library, Python and numba dispatch time handed on to the stage of ours that called it (by cProfile's "
             "per-caller own time, up through library callers), so that column shows what each of our stages costs, "
             "numpy included. A compiled numba kernel is its own entry, counted in its module's stage. The profiler "
             "slows Python-level calls much more than compiled ones, so the profiled time exceeds the median and "
             "Python-heavy stages weigh more than they do unprofiled; \"≈ ms at the median\" is that share times the "
             "unprofiled median, an estimate.", ""]
    for record in results["workloads"]:
        overhead = record["profiled_ms_per_call"] / record["median_ms"] if record["median_ms"] > 0 else float("nan")
        lines += [f"### {record['title']}", "",
                  f"{record['what']}. Median {record['median_ms']:.1f} ms per call without the profiler "
                  f"({plural(record['repeat'], 'call')}: {counted(record['outcomes'])}); "
                  f"{record['profiled_ms_per_call']:.1f} ms per call under cProfile "
                  f"({plural(record['calls'], 'call')}: {counted(record['profiled_outcomes'])}; "
                  f"{overhead:.2f}× the median, {record['function_calls'] / record['calls']:.0f} Python and built-in "
                  f"function calls per call). {dominates(record)}", "",
                  *stage_table(record), "", *top_table(record), ""]
    for note in results.get("notes", []):
        lines += [f"{note}", ""]
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--repeat", type=int, default=9, help="timed calls per simulated workload (default 9)")
    parser.add_argument("--calls", type=int, default=50, help="profiled calls per simulated workload (default 50)")
    parser.add_argument("--image-repeat", type=int, default=5, help="timed solves per real image (default 5)")
    parser.add_argument("--image-calls", type=int, default=5, help="profiled solves per real image (default 5)")
    parser.add_argument("--only", help=f"comma-separated workloads of {', '.join(SIMULATED)}, real (default: all)")
    parser.add_argument("--images", default=",".join(REAL_IMAGES),
                        help=f"comma-separated real image ids of the manifest (default {','.join(REAL_IMAGES)})")
    parser.add_argument("--corpus", type=Path, help="corpus folder holding MANIFEST.json (default ../shared/realdata)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: 2 timed and 2 profiled calls per simulated workload, 1 and 1 per real image")
    parser.add_argument("--output", type=Path, help=f"write the '{HEADER[3:]}' section of this Markdown file")
    parser.add_argument("--json", type=Path, help="raw results (default: bench_profile.json beside --output)")
    parser.add_argument("--from-json", type=Path, metavar="JSON",
                        help="measure nothing: write the section of --output from these saved results")
    args = parser.parse_args(argv)
    if args.from_json:
        text = render_markdown(json.loads(args.from_json.read_text()))
        print(text)
        if args.output:
            write_section(args.output, text)
        return 0
    only = {name.strip() for name in (args.only or ",".join(SIMULATED + ("real",))).split(",") if name.strip()}
    unknown = sorted(only - set(SIMULATED) - {"real"})
    if unknown:
        parser.error(f"unknown workload(s) {', '.join(unknown)}; choose from {', '.join(SIMULATED)}, real")
    repeat, calls = (2, 2) if args.quick else (args.repeat, args.calls)
    image_repeat, image_calls = (1, 1) if args.quick else (args.image_repeat, args.image_calls)
    if min(repeat, calls, image_repeat, image_calls) < 1:
        parser.error("--repeat, --calls, --image-repeat and --image-calls must be at least 1")
    from star_tracker.process_memory import keep_freed_memory

    keep_freed_memory()  # as the `star-tracker` command and the nodes run
    started, date, load = time.perf_counter(), utc_now(), list(os.getloadavg())
    notes = []
    workloads = simulated_workloads(only) if only & set(SIMULATED) else []
    if "real" in only:
        try:
            corpus = find_corpus(args.corpus)
        except CorpusMissing as exc:
            notes.append(f"Real images: skipped ({exc}).")
        else:
            workloads += image_workloads(corpus, [i.strip() for i in args.images.split(",") if i.strip()])
    records = []
    for index, workload in enumerate(workloads):
        records.append(measure(workload, image_repeat if workload.image else repeat,
                               image_calls if workload.image else calls))
        report_progress(index + 1, len(workloads), workload.name)
        print(f"{workload.name}: median {records[-1]['median_ms']:.1f} ms, profiled "
              f"{records[-1]['profiled_ms_per_call']:.1f} ms per call", file=sys.stderr, flush=True)
    meta = {"command": "python -m bench.bench_profile" + "".join(
        f" {shlex.quote(a)}" for a in (argv if argv is not None else sys.argv[1:])), "date": date,
        "elapsed_s": time.perf_counter() - started, "load_average": load, "quick": args.quick, "seed": SEED,
        **machine_info()}
    results = {"meta": meta, "workloads": records, "notes": notes}
    text = render_markdown(results)
    print(text)
    if args.output:
        write_section(args.output, text)
    json_path = args.json or (args.output.parent / "bench_profile.json" if args.output else None)
    if json_path:
        json_path.write_text(json.dumps(results, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
