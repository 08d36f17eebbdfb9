# SPDX-License-Identifier: Apache-2.0
"""
Real-image solves against the PSF width: the estimate's error must not break a solve.

Each image of the real corpus (../shared/realdata) is solved by `star-tracker solve IMG --fov F`
at its defaults (the PSF estimated from the image), then with the PSF fixed (`--psf-sigma`) at
the estimate times each FACTORS value: the widths a frame's estimate can land on when it is
made from other stars (its own 1-sigma is 2-10 %). Per image and width: solved, matched stars,
boresight error against the image's reference (bench/corpus.py: the dense re-fit where the
manifest has one). A cliff (a solve lost, or fewer than CLIFF_SHARE of the default's stars, or a
solve within 1' at the default moved beyond it) is a fault of the pipeline, not of the image
(such as a singular blend fit's runaway covariance, or pattern scales 1 % off on a trailed frame).

`python -m bench.bench_psf_sensitivity --output docs/BENCHMARKS.md` (about 2 min on 2 cores).
"""
from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from bench.corpus import CorpusMissing, attitude_errors, find_corpus, load_corpus, run_solve_command, solve_argv
from bench.machine import machine_info, utc_now
from bench.report import write_section

FACTORS = (0.85, 0.9, 0.95, 1.05, 1.1, 1.15)
CLIFF_SHARE = 0.8  # fewer than this share of the default solve's stars at a width is a cliff
ARCMIN = math.radians(1.0 / 60.0)
HEADER = "## Real images against the PSF width"


def _solve(argv: list[str], image) -> dict:
    from star_tracker.models.attitude import quaternion_to_matrix

    code, record, _, err = run_solve_command(argv)
    if code != 0 or record is None:
        return {"solved": False, "stars": 0, "boresight_arcsec": None,
                "reason": (record or {}).get("reason") or err.strip()[-200:]}
    boresight = None
    if image.reference is not None:
        rotation = quaternion_to_matrix(np.asarray(record["quaternion_xyzw"], float))
        boresight = math.degrees(attitude_errors(rotation, image.reference)[0]) * 3600.0
    return {"solved": True, "stars": len(record["matched"]), "boresight_arcsec": boresight,
            "sigma_px": record["psf"]["sigma_px"], "quat_xyzw_sensor_to_icrs": record["quaternion_xyzw"]}


def cliff(default: dict, at_width: dict) -> bool:
    """Whether a solve at a fixed width fell off a cliff against the default's."""
    if not default["solved"]:
        return False
    if not at_width["solved"] or at_width["stars"] < CLIFF_SHARE * default["stars"]:
        return True
    within = default["boresight_arcsec"] is not None and default["boresight_arcsec"] <= 60.0
    return within and at_width["boresight_arcsec"] > 60.0


def run(images, log=print) -> list[dict]:
    rows = []
    for image in images:
        argv = solve_argv(image)
        run_solve_command(argv)  # databases and kernels loaded: untimed, as every run here
        started = time.perf_counter()
        default = _solve(argv, image)
        widths = []
        if default["solved"]:
            for factor in FACTORS:
                sigma = default["sigma_px"] * factor
                result = _solve(argv + ["--psf-sigma", f"{sigma:.3f}"], image)
                widths.append(dict(result, factor=factor, psf_sigma_px=round(sigma, 3),
                                   cliff=cliff(default, result)))
        rows.append({"id": image.id, "default": default, "widths": widths,
                     "elapsed_s": round(time.perf_counter() - started, 2)})
        log(f"{image.id}: {default['stars']} stars at defaults; "
            + " ".join(f"{w['stars']}{'!' if w['cliff'] else ''}" for w in widths))
    return rows


def _cell(result: dict) -> str:
    if not result["solved"]:
        return "**not solved**" if result.get("cliff") else "not solved"
    text = f"{result['stars']}"
    if result["boresight_arcsec"] is not None:
        text += f" / {result['boresight_arcsec']:.0f}″"
    return f"**{text}**" if result.get("cliff") else text


def render_markdown(rows: list[dict], meta: dict) -> str:
    lines = [HEADER, "",
             f"Command: `{meta['command']}`. Measured {meta['date']} in {meta['elapsed_s']:.0f} s. Machine: "
             f"{meta['cpu']}, `nproc` = {meta['cores']}; Python {meta['python']}.", "",
             "Each image of `../shared/realdata` solved by `star-tracker solve IMG --fov <fov_h_deg>` at its "
             "defaults (the PSF σ estimated from the image), then with `--psf-sigma` fixed at that estimate times "
             "each factor: the widths an estimate made from other stars could give. Cell: matched stars / boresight "
             "error against the image's reference (the dense re-fit where the manifest has one, else the "
             f"astrometry.net solve: § Real images). **Bold**: a cliff (not solved, fewer than {CLIFF_SHARE:.0%} "
             "of the default's stars, or a default within 1′ moved beyond it).", "",
             "| image | estimated σ px | defaults | " + " | ".join(f"σ × {f:g}" for f in FACTORS) + " |",
             "|---|---:|---:|" + "---:|" * len(FACTORS)]
    for row in rows:
        default = row["default"]
        sigma = f"{default['sigma_px']:.2f}" if default["solved"] else "–"
        cells = [_cell(w) for w in row["widths"]] or ["–"] * len(FACTORS)
        lines.append(f"| {row['id']} | {sigma} | {_cell(default)} | " + " | ".join(cells) + " |")
    solved = [r for r in rows if r["default"]["solved"]]
    cliffs = [(r["id"], w["factor"]) for r in solved for w in r["widths"] if w["cliff"]]
    lines += ["", f"Summary: {len(solved)} of {len(rows)} images solved at defaults; {len(cliffs)} cliffs in "
              f"{len(solved) * len(FACTORS)} fixed-width solves"
              + (": " + ", ".join(f"{name} at σ × {factor:g}" for name, factor in cliffs) if cliffs else "") + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().split("\n\n")[0])
    parser.add_argument("--output", type=Path, help=f"write the '{HEADER[3:]}' section of this Markdown file")
    parser.add_argument("--json", type=Path, help="raw results (default: bench_psf_sensitivity.json beside --output)")
    parser.add_argument("--only", help="comma-separated image ids of the manifest (default: all)")
    parser.add_argument("--corpus", type=Path, help="corpus folder holding MANIFEST.json")
    parser.add_argument("--from-json", type=Path, metavar="JSON",
                        help="solve nothing: write the section of --output from these saved results")
    args = parser.parse_args(argv)
    if args.from_json:
        saved = json.loads(args.from_json.read_text())
        text = render_markdown(saved["images"], saved["meta"])
        print(text)
        if args.output:
            write_section(args.output, text)
        return 0
    try:
        corpus = find_corpus(args.corpus)
    except CorpusMissing as exc:
        print(f"bench_psf_sensitivity: {exc}", file=sys.stderr)
        return 2
    from star_tracker.process_memory import keep_freed_memory

    keep_freed_memory()
    only = [name.strip() for name in args.only.split(",") if name.strip()] if args.only else None
    started = time.perf_counter()
    date = utc_now()
    rows = run(load_corpus(corpus, only), log=lambda text: print(text, file=sys.stderr, flush=True))
    info = machine_info()
    meta = {"command": "python -m bench.bench_psf_sensitivity" + "".join(
        f" {shlex.quote(a)}" for a in (argv if argv is not None else sys.argv[1:])), "date": date,
        "elapsed_s": time.perf_counter() - started, "cpu": info["cpu"], "cores": info["cores"],
        "python": info["python"], "factors": list(FACTORS), "cliff_share": CLIFF_SHARE}
    text = render_markdown(rows, meta)
    print(text)
    if args.output:
        write_section(args.output, text)
    json_path = args.json or (args.output.parent / "bench_psf_sensitivity.json" if args.output else None)
    if json_path:
        json_path.write_text(json.dumps({"meta": meta, "images": rows}, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
