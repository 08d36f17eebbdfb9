# SPDX-License-Identifier: Apache-2.0
"""The datasheet (bench/datasheet.py, docs/DATASHEET.md): drawn from the benchmarks' results, and kept current."""
from __future__ import annotations

import json
import math
import shutil
import sys
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import datasheet  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
CONFIG = yaml.safe_load((REPO / "config" / "star_tracker.yaml").read_text())


def test_committed_datasheet_is_the_one_the_results_give():
    """docs/DATASHEET.md is what the committed results and defaults give (rerun `python -m bench.datasheet`)."""
    assert (DOCS / "DATASHEET.md").read_text() == datasheet.render(CONFIG, DOCS), \
        "docs/DATASHEET.md is stale: run `python -m bench.datasheet` (star-tracker bench does it last)"


def test_figures_are_the_results_figures():
    """Values come from the JSON results, each row names its benchmark's date and machine."""
    text = datasheet.render(CONFIG, DOCS)
    attitude = json.loads((DOCS / "bench_attitude.json").read_text())
    rest = next(case for case in attitude["cases"] if case["name"] == "at rest")
    row = next(line for line in text.splitlines() if line.startswith("| Attitude error at rest"))
    assert f"{rest['cross_rms_arcsec']:.2f}″ cross-boresight, {rest['roll_rms_arcsec']:.2f}″ roll" in row
    assert attitude["meta"]["date"] in row
    realdata = json.loads((DOCS / "bench_realdata.json").read_text())["summary"]["ours"]
    row = next(line for line in text.splitlines() if line.startswith("| Real sky images"))
    assert f"{realdata['solved']} of {realdata['images']} solved" in row
    orbit = json.loads((DOCS / "bench_orbit.json").read_text())
    row = next(line for line in text.splitlines() if line.startswith("| Fused error per body axis"))
    assert ", ".join(f"{v:.2f}" for v in orbit["fusion"]["rms_two_heads_arcsec"]) + "″" in row
    assert orbit["meta"]["date"] in row
    sky = json.loads((DOCS / "characterize_sky_coverage.json").read_text())
    row = next(line for line in text.splitlines() if line.startswith("| Lost-in-space over the sky"))
    assert f"{100 * sky['success']:.2f} % of {sky['trials']:,} solved right ({sky['wrong']} wrong)" in row
    assert sky["date_utc"] in row and "CHARACTERIZE.md" in row
    assert datasheet.NOT_MEASURED not in text  # every benchmark and campaign has committed results
    # The default camera's pixel scale from the parameter file: 15 deg over 1024 px.
    focal = 512.0 / math.tan(math.radians(7.5))
    assert f"{datasheet.ARCSEC_PER_RAD / focal:.1f}″ per pixel" in text


def test_a_benchmark_not_run_is_named_not_invented(tmp_path):
    shutil.copy(DOCS / "bench_attitude.json", tmp_path)
    text = datasheet.render(CONFIG, tmp_path)
    assert "| Attitude error at rest" in text
    lost = next(line for line in text.splitlines() if line.startswith("| Lost-in-space identification"))
    assert datasheet.NOT_MEASURED in lost and "bench_identify" in lost
    assert text.count(datasheet.NOT_MEASURED) == 16  # identify, tracking, centroid, psf range, pipeline, larger
    # sensor, soak, cold start, real images, orbit, environment; the campaigns false-id, sky-coverage, accuracy,
    # tracking; the characterization report (datasheet.json)
