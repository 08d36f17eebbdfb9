# SPDX-License-Identifier: Apache-2.0
"""
The profile benchmark (bench/bench_profile.py): its stages, and its section from a --quick run.

Counted outcomes only, never times: the section holds a stage table and a function table per
workload, each workload's stage shares add up to the whole profile, the JSON names every workload
with its calls, and the real images appear when ../shared/realdata is there (a note when not).
"""
from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_profile as bench  # noqa: E402
from bench import corpus as real_corpus  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


def corpus_present() -> bool:
    try:
        real_corpus.find_corpus()
    except real_corpus.CorpusMissing:
        return False
    return True


def test_stages_by_module():
    """A function's stage comes from its module; C built-ins by the library they belong to."""
    package = REPO / "star_tracker"
    cases = {
        (package / "centroid/detection/detect.py", "detect"): "detection",
        (package / "centroid/psf/gaussian_fit_kernel.py", "fit_single_psf"): "PSF estimate and point fits",
        (package / "centroid/psf_loop.py", "estimate_psf"): "PSF estimate and point fits",
        (package / "centroid/streak/free_fit_kernel.py", "_fit_segments"): "streak fits",
        (package / "centroid/tracks/track_peaks.py", "f"): "track and blend screening",
        (package / "centroid/extract.py", "extract_spots"): bench.OTHER_CENTROID,
        (package / "identify/kernels.py", "q_method"): "identification",
        (package / "track/tracking.py", "process"): "tracking",
        (package / "models/attitude.py", "f"): "models",
        (package / "commands/solve.py", "run"): "solve command",
        (package / "commands/images.py", "read_image"): "image read",
        (REPO / "bench/corpus.py", "run_solve_command"): bench.HARNESS,
        (package / "sim/render.py", "render"): bench.OTHER_PACKAGE,
        (Path("/x/.venv/lib/python3.11/site-packages/numba/core/dispatcher.py"), "_compile_for_args"):
            "numba dispatch",
        (Path("/x/.venv/lib/python3.11/site-packages/numpy/fft/_pocketfft.py"), "_raw_fft"): bench.LIBRARY,
        (Path(bench.STDLIB) / "json/encoder.py", "_iterencode_dict"): bench.PYTHON,
    }
    for (path, function), stage in cases.items():
        assert bench.stage_of(str(path), function) == stage, path
    assert bench.stage_of("~", "<method 'reduce' of 'numpy.ufunc' objects>") == bench.LIBRARY
    assert bench.stage_of("~", "<built-in method builtins.len>") == bench.PYTHON
    import cv2  # noqa: F401  (cv2's functions carry no module name: "<imread>")

    assert bench.stage_of("~", "<imread>") == bench.LIBRARY and bench.display_name("~", 0, "<imread>") == "cv2.imread"
    assert set(bench.STAGE_ORDER) >= {label for label, _ in bench.STAGES} | {bench.LIBRARY, bench.PYTHON}


def test_library_time_goes_to_the_stage_calling_it():
    """Library time is handed to our callers by the time spent for each, up through library callers."""
    ours_a, ours_b = (str(REPO / "star_tracker/centroid/detection/detect.py"), 1, "a"), \
        (str(REPO / "star_tracker/identify/kernels.py"), 1, "b")
    wrapper = ("/v/site-packages/numpy/_core/fromnumeric.py", 1, "sum")
    builtin = ("~", 0, "<method 'reduce' of 'numpy.ufunc' objects>")
    stats = {  # key: (primitive calls, calls, tottime, cumtime, {caller: (calls, primitive, tottime, cumtime)})
        ours_a: (1, 1, 1.0, 5.0, {}),
        ours_b: (1, 1, 1.0, 3.0, {}),
        wrapper: (2, 2, 0.5, 4.0, {ours_a: (1, 1, 0.25, 3.0), ours_b: (1, 1, 0.25, 1.0)}),
        builtin: (3, 3, 4.5, 4.5, {wrapper: (2, 2, 3.5, 3.5), ours_b: (1, 1, 1.0, 1.0)}),
    }
    stage = {key: bench.stage_of(key[0], key[2]) for key in stats}
    shares = bench.callers_stages(stats, builtin, stage, {}, set())
    # 3.5 of 4.5 through the wrapper (split evenly between a and b), 1.0 of 4.5 from b directly.
    assert shares == pytest.approx({"detection": 1.75 / 4.5, "identification": 2.75 / 4.5})


def test_real_images_skipped_with_a_note_without_the_corpus(tmp_path, capsys):
    doc = tmp_path / "BENCHMARKS.md"
    assert bench.main(["--only", "real", "--corpus", str(tmp_path / "absent"), "--output", str(doc)]) == 0
    results = json.loads((tmp_path / "bench_profile.json").read_text())
    assert results["workloads"] == [] and len(results["notes"]) == 1
    assert "Real images: skipped" in doc.read_text()


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("profile")
    doc = folder / "BENCHMARKS.md"
    doc.write_text("# Benchmarks\n\n## Before\n\nkept\n\n## Profiles\n\nold\n\n## After\n\nkept too\n")
    assert bench.main(["--quick", "--output", str(doc)]) == 0
    return doc.read_text(), json.loads((folder / "bench_profile.json").read_text())


@pytest.mark.slow  # renders frames, loads the kernels and the databases, solves three real images: ~10 s, busy VM
def test_quick_run_section_and_results(quick_run):
    text, results = quick_run
    expected = list(bench.SIMULATED) + ([f"real_{i}" for i in sorted(bench.REAL_IMAGES)] if corpus_present() else [])
    records = {record["name"]: record for record in results["workloads"]}
    assert sorted(records) == sorted(expected)
    # The section replaced the old one, the rest of the file kept.
    assert text.count(bench.HEADER) == 1 and "old" not in text and "## Before\n\nkept" in text
    assert text.rstrip().endswith("## After\n\nkept too")
    section = text[text.index(bench.HEADER):text.index("## After")]
    blocks = section.split("\n### ")[1:]
    assert len(blocks) == len(expected)
    for record in results["workloads"]:
        assert record["calls"] >= 1 and record["repeat"] >= 1 and record["function_calls"] > 0
        assert sum(record["outcomes"].values()) == record["repeat"]
        assert sum(record["profiled_outcomes"].values()) == record["calls"]
        assert sum(s["share"] for s in record["stages"]) == pytest.approx(1.0, abs=1e-9)
        assert sum(s["share_with_calls"] for s in record["stages"]) == pytest.approx(1.0, abs=1e-9)
        assert {s["stage"] for s in record["stages"]} <= set(bench.STAGE_ORDER)
        assert 1 <= len(record["top"]) <= bench.TOP
        [block] = [b for b in blocks if b.startswith(record["title"] + "\n")]
        rows = [line for line in block.splitlines() if line.startswith("| ") and " % |" in line]
        stage_rows = [row for row in rows if row.split(" | ")[0][2:] in bench.STAGE_ORDER]
        assert len(stage_rows) == len(record["stages"])
        own = [float(value) for value in re.findall(r"\| ([\d.]+) % \| [\d.]+ \| [\d.]+ % \|", block)]
        assert len(own) == len(record["stages"]) and sum(own) == pytest.approx(100.0, abs=0.1 * len(own))
        assert len(rows) - len(stage_rows) == len(record["top"])  # the function table
        assert "Dominated by" in block
    # Every simulated workload did what it times: spots found, the frame solved, tracking kept.
    assert all(label.endswith(" spots") and int(label.split()[0]) > 50 for name in ("nominal", "slewing")
               for label in records[name]["outcomes"])
    assert set(records["lost_in_space"]["outcomes"]) == set(records["lost_in_space_cold"]["outcomes"]) == {"solved"}
    assert set(records["tracking"]["outcomes"]) == {"tracking"}
    assert ("### Real image " in section) == corpus_present()
