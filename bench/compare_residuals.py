# SPDX-License-Identifier: Apache-2.0
"""
Our centroids on the real corpus, two runs compared: each image's RMS residual over the stars both runs match.

    python -m bench.bench_realdata --no-peers --json A.json   # at one commit (PYTHONPATH at its worktree)
    python -m bench.bench_realdata --no-peers --json B.json   # at another
    python -m bench.compare_residuals A.json B.json [C.json ...]

A residual is a matched star's angle from its catalogue direction after `solve`'s attitude and
camera fit [arcsec] (`solve --json` matched[].residual_arcsec). Over the same stars, a lower RMS
means centroids that agree better with the catalogue; a shift common to every star (a boresight
offset) does not change it. Prints the images where the runs differ by more than 0.005".
"""
from __future__ import annotations

import argparse
import json

import numpy as np


def per_image(path: str) -> dict[str, dict[str, float]]:
    """Image id -> {HIP: residual [arcsec]} of our solver in a bench_realdata JSON."""
    with open(path) as f:
        doc = json.load(f)
    return {row["id"]: row["solvers"]["ours"].get("residual_arcsec_by_hip") or {} for row in doc["images"]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="bench_realdata --json files, first = the reference")
    args = parser.parse_args(argv)
    runs = [per_image(p) for p in args.runs]
    print("| image | stars | " + " | ".join(f"{p} ″" for p in args.runs) + " |")
    print("|---|---:|" + "---:|" * len(runs))
    for image in runs[0]:
        common = set(runs[0][image])
        for run in runs[1:]:
            common &= set(run.get(image, {}))
        if not common:
            continue
        rms = [float(np.sqrt(np.mean(np.square([run[image][h] for h in sorted(common)])))) for run in runs]
        if max(rms) - min(rms) > 0.005:
            print(f"| {image} | {len(common)} | " + " | ".join(f"{v:.2f}" for v in rms) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
