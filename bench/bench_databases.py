# SPDX-License-Identifier: Apache-2.0
"""
Pattern-database build and load times and sizes (goal: build <= 10 s, load < 1 s).

Each database is built into an empty temporary cache (so nothing is reused), then loaded
back from it in a fresh call, best of 3 loads. Writes the "## Pattern databases" table to
stdout (and as the "## Pattern databases" section of --output, with bench_databases.json
beside it).

    python -m bench.bench_databases [--output docs/BENCHMARKS.md]
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from star_tracker.models.catalog import load_hipparcos
from star_tracker.models.file_memo import forget_all
from star_tracker.identify import DatabaseConfig, load_or_build_database
from star_tracker.identify import triangle_database as triangle_module
from star_tracker.identify.triangle_database import TriangleConfig, load_or_build_triangles
from .machine import machine_info, machine_text, utc_now
from .report import write_section

CASES = [
    ("nominal 15 deg, Hp <= 6.5 (default)", DatabaseConfig()),
    ("Cole 8 deg, mag 6.0", DatabaseConfig(magnitude_limit=6.0, max_pair_angle_rad=float(np.radians(8.2)))),
    ("FAST 11.3 deg, Hp <= 7.0", DatabaseConfig(magnitude_limit=7.0, max_pair_angle_rad=float(np.radians(11.5)))),
]


def _cache_bytes(directory: Path, prefix: str) -> int:
    return sum(p.stat().st_size for p in directory.glob(prefix + "*"))


def measure(label: str, config: DatabaseConfig) -> list[list[str]]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["STAR_TRACKER_CACHE"] = tmp
        directory = Path(tmp)
        load_hipparcos()  # the parsed catalog is cached too; not part of a pattern build
        started = time.perf_counter()
        database = load_or_build_database(config, directory)
        build = time.perf_counter() - started
        loads = []
        for _ in range(3):
            forget_all()  # measure the load from disk, not the in-process memo (models/file_memo.py)
            started = time.perf_counter()
            load_or_build_database(config, directory)
            loads.append(time.perf_counter() - started)
        rows.append([label, "star pairs (k-vector)", f"{database.star_count}", f"{database.pair_a.size:,}",
                     f"{build:.2f}", f"{min(loads):.2f}", f"{_cache_bytes(directory, 'pairs_') / 1e6:.1f}"])
        started = time.perf_counter()
        triangles = load_or_build_triangles(database, TriangleConfig.for_database(database))
        build = time.perf_counter() - started
        loads = []
        for _ in range(3):
            triangle_module._MEMO.clear()  # measure the load from disk, not the in-process memo
            started = time.perf_counter()
            load_or_build_triangles(database, TriangleConfig.for_database(database))
            loads.append(time.perf_counter() - started)
        count = int(triangles.spherical.stars.shape[0])
        size = sum(p.stat().st_size for p in directory.glob("*") if not p.name.startswith(("pairs_", "hip2_")))
        rows.append([label, "triangles (spherical + planar features)", f"{int(triangles.guide_stars.size)}",
                     f"{count:,}", f"{build:.2f}", f"{min(loads):.2f}", f"{size / 1e6:.1f}"])
    return rows


HEADER = ["setup", "database", "stars", "entries", "build [s]", "load [s]", "size [MB]"]


def render_markdown(results: dict) -> str:
    meta = results["meta"]
    lines = ["## Pattern databases", "",
             f"Command: `{meta['command']}`. Measured {meta['date']} in {meta['elapsed_s']:.0f} s on a shared host. "
             f"Machine: {machine_text(meta)}. Raw results: `docs/bench_databases.json`.", "",
             "Built into an empty cache; load = best of 3 loads of the cached file (checksum validated).", "",
             "| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(r) + " |" for r in results["rows"]]
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--output", type=Path, default=None, help="markdown file to write the section into")
    args = parser.parse_args(argv)
    started, date = time.perf_counter(), utc_now()
    rows = [row for label, config in CASES for row in measure(label, config)]
    meta = {"command": "python -m bench.bench_databases" + "".join(
        f" {shlex.quote(a)}" for a in (argv if argv is not None else sys.argv[1:])), "date": date,
        "elapsed_s": time.perf_counter() - started, **machine_info()}
    text = render_markdown({"meta": meta, "rows": rows})
    print(text)
    if args.output:
        write_section(args.output, text)
        (args.output.parent / "bench_databases.json").write_text(
            json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
