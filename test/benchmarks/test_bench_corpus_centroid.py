# SPDX-License-Identifier: Apache-2.0
"""
The corpus centroiding-time benchmark (bench/bench_corpus_centroid.py) and its stage split.

On one real corpus image (skipped where ../shared/realdata is absent): the stages it reports
are parts of the centroiding it times, and its section says so.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_corpus_centroid as bench  # noqa: E402
from bench import corpus as real_corpus  # noqa: E402

IMAGE = "ubst_webcam_w1"  # the corpus's smallest frame (640x480): a few ms a run


@pytest.fixture
def corpus() -> Path:
    try:
        return real_corpus.find_corpus()
    except real_corpus.CorpusMissing as exc:
        pytest.skip(str(exc))


def test_stages_are_parts_of_the_centroiding(corpus, tmp_path, monkeypatch):
    """Every stage is timed on a real frame; the stages that do not nest add up to no more than the total."""
    for _, module_name, name in bench.STAGES:  # the wrappers are undone after the test
        module = sys.modules.get(module_name) or __import__(module_name, fromlist=[name])
        monkeypatch.setattr(module, name, getattr(module, name))
    doc = tmp_path / "BENCHMARKS.md"
    # One run: each stage's time lies inside that run's total (medians over runs need not add up).
    assert bench.main(["--corpus", str(corpus), "--repeat", "1", "--only", IMAGE, "--output", str(doc)]) == 0
    results = json.loads((tmp_path / "bench_corpus_centroid.json").read_text())
    [row] = results["images"]
    stages = row["stages_ms"]
    assert row["id"] == IMAGE and set(stages) == {label for label, _, _ in bench.STAGES}
    for label in ("detection", "candidate measurement", "PSF estimate", "point fits", "streak fits"):
        assert stages[label] > 0.0, label  # this frame has point-like and elongated spots
    # The free streak fit and the streak residual run inside the streak fits, the rest one after
    # another inside the total (0.01 ms a value of rounding).
    assert stages["free streak fit (compiled)"] + stages["streak residual"] <= stages["streak fits"] + 0.02
    top_level = [label for label in stages if label not in bench.NESTED]
    assert sum(stages[label] for label in top_level) <= row["total_ms"] + 0.06
    text = doc.read_text()
    assert bench.HEADER in text and f"| {IMAGE} | 640×480 |" in text


def test_cedar_solve_time_is_read_beside_the_output(tmp_path):
    """cedar-solve's whole time per image comes from the real-image benchmark's results, where it solved."""
    (tmp_path / "bench_realdata.json").write_text(json.dumps({"images": [
        {"id": "a", "solvers": {"cedar-solve": {"solved": True, "time_s": 0.025}}},
        {"id": "b", "solvers": {"cedar-solve": {"solved": False, "time_s": 5.0}}}]}))
    assert bench.cedar_times_ms(tmp_path) == {"a": 25.0}
    assert bench.cedar_times_ms(tmp_path / "absent") == {}
    rows = [{"id": name, "width": 640, "height": 480, "spots": 25, "total_ms": total,
             "stages_ms": {label: 1.0 for label, _, _ in bench.STAGES}} for name, total in (("a", 20.0), ("b", 9.0))]
    text = bench.render_markdown({"meta": {"command": "test", "date": "now", "elapsed_s": 1.0, "repeat": 7},
                                  "images": rows, "cedar_solve_ms": {"a": 25.0}})
    assert "| a | 640×480 | 25 | 20.0 |" in text and text.rstrip().endswith("range 0.80-0.80.")
    assert "| b | 640×480 | 25 | 9.0 | " in text and "| not solved |" in text
