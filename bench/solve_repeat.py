# SPDX-License-Identifier: Apache-2.0
"""
One real-corpus image solved again and again in one process: how steady the command's time is.

    python -m bench.solve_repeat unh_DSC_0080 [--repeats 12] [--default-malloc]

Runs `star-tracker solve IMG --fov <fov_h_deg> --json` in-process (bench_realdata's call) and
prints each repeat's --json timing_s (read, centroid, solve, total) and their range. The process
keeps freed memory as the command does (star_tracker/process_memory.py) unless
--default-malloc: glibc's defaults, freed image buffers handed back to the kernel.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().split("\n\n")[0])
    parser.add_argument("image", help="an image id of ../shared/realdata/MANIFEST.json")
    parser.add_argument("--repeats", type=int, default=12)
    parser.add_argument("--default-malloc", action="store_true", help="leave glibc's malloc at its defaults")
    args = parser.parse_args(argv)
    from bench import bench_realdata as realdata

    if not args.default_malloc:
        from star_tracker.process_memory import keep_freed_memory

        keep_freed_memory()
    try:
        image = realdata.load_corpus(realdata.find_corpus(), [args.image])[0]
    except (realdata.CorpusMissing, IndexError) as exc:
        print(f"solve_repeat: {exc or 'no such image'}", file=sys.stderr)
        return 2
    argv_solve = realdata.solve_argv(image)
    rows = []
    for _ in range(args.repeats):
        code, record, _, err = realdata.run_solve_command(argv_solve)
        if code != 0 or record is None:
            print(f"solve_repeat: exit code {code}: {err.strip()[-300:]}", file=sys.stderr)
            return 1
        rows.append(record["timing_s"])
        print(" ".join(f"{k} {v:.3f}" for k, v in rows[-1].items()), flush=True)
    for key in ("centroid", "total"):
        values = np.array([r[key] for r in rows[1:]])  # the first repeat loads the databases
        print(f"{key}: min {values.min():.3f} median {np.median(values):.3f} max {values.max():.3f} s "
              f"over repeats 2-{len(rows)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
