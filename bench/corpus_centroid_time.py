# SPDX-License-Identifier: Apache-2.0
"""
Centroiding CPU time per real-corpus image, in-process: what `star-tracker solve IMG` spends in extract_spots.

    python -m bench.corpus_centroid_time [--corpus DIR] [--repeat 7] [IMAGE_ID ...]

Prints JSON {image id: median CPU time [ms]} over `--repeat` runs after a warm one (CPU
time: the VM's steal does not count; compare runs made in alternation). For an A/B against
another commit, run it with PYTHONPATH at a worktree of that commit, in alternation:

    (cd ../wt && PYTHONPATH=. python /path/to/repo/bench/corpus_centroid_time.py --corpus ../shared/realdata)
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path


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
    args = parser.parse_args(argv)
    corpus = find_corpus(args.corpus)
    manifest = json.loads((corpus / "MANIFEST.json").read_text())["images"]
    chosen = [image for image in manifest if not args.ids or image["id"] in args.ids]
    times = {}
    for entry in chosen:
        image = read_image(corpus / entry["file"])
        config = centroid_config(image.pixels, image.description,
                                 build_parser().parse_args(["solve", "x", "--fov", str(entry["fov_h_deg"])]))
        extract_spots(image.pixels, config)
        runs = []
        for _ in range(args.repeat):
            started = time.process_time()
            extract_spots(image.pixels, config)
            runs.append(time.process_time() - started)
        times[entry["id"]] = round(1000.0 * statistics.median(runs), 2)
    print(json.dumps(times))


if __name__ == "__main__":
    main(sys.argv[1:])
